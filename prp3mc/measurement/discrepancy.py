"""Where model and measurement disagree, which effect is missing, and the gap.

Model of a measurement
----------------------
Measurement m of commanded pose p is ``measured = commanded + e_m + s_m + n_m``:

- ``e_m`` is the budget's random pose error, drawn afresh at every
  measurement (clearances settle at a new contact angle and encoders read a
  new count error each time a pose is approached; repeats of a pose are
  therefore independent). Its mean ``mu_p`` is *not* zero (encoder errors
  are one-sided) and its covariance is ``Sigma_p``; both are exact moments of
  the linear model (:meth:`prp3mc.LinearModel.moments`), which the exact
  nonlinear chain matches to < 0.1 um at these magnitudes.
- ``s_m = sum_k theta_k g_k(m)`` are systematic effects of the library, each
  linear in its value through its signature (:func:`prp3mc.measurement.effects.signatures`).
- ``n_m`` is instrument noise, N(0, diag(s_mm^2, s_mm^2, s_deg^2)).

Inference uses the Gaussian likelihood of the residuals ``measured -
commanded - mu_p`` with covariance ``V_p = Sigma_p + N``; systematic values
are generalized least squares (exact covariance whatever the error law), a
spread effect scales one input's law about 0 so its contribution to
``(mu_p, Sigma_p)`` becomes ``(f mu_p, f^2 Sigma_p)`` and ``f`` is found by
maximum likelihood with a profile-likelihood interval.

Channels and tests
------------------
Whitening the residuals by ``V_p^{-1/2}`` gives vectors z_m with mean 0 and
covariance I when the model is right. Per pose, the *systematic* statistic
is ``B_p = n_p |mean z|^2`` (about chi2(3)) and the *dispersion* statistic
``S_p = sum |z_m - mean z|^2`` (mean 3 (n_p - 1)); their null variances,
which depend on the budget's non-Gaussian laws, come from a parametric
bootstrap of the linear model, and p-values from scaled chi-square laws with
matched mean and variance. Global tests sum them over poses; per-pose tests
are controlled by Benjamini-Hochberg (maps) and Holm (decisions).

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

Naming
------
Forward selection over the library: at each step every testable candidate
is added in turn to the current model; the best by likelihood ratio (LR) is
accepted only if its LR passes chi2(1) at level ``alpha / K`` (Bonferroni
over the K candidates tried). Candidates whose LR is within the chi2(1) 99 %
quantile of the best are its *aliases*: the campaign cannot tell them apart,
the named effect is then reported with ``identified: false`` and each alias
with its own value and interval. After each acceptance all accepted values
are refitted jointly and any accepted effect that is no longer significant
(LR of removal below the chi2(1) quantile at ``alpha``) is dropped. Effects
whose signature vanishes over the campaign (e.g. ``c_i`` and ``e_i`` when
theta_i = 0) are reported as invisible and never named. When no candidate
passes, remaining disagreement (six global, per-pose, spatial and
lack-of-fit tests at family-wise level ``alpha_unexplained``) sets
``unexplained``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import optimize, stats

from .._rng import resolve_rng
from .._version import __version__
from ..uncertainty.budget import Budget
from .campaign import Campaign, read_campaign
from .effects import EFFECT_NAMES, effect, library, signatures, spread_budget, spread_reference
from ..errors import BudgetError
from ..kinematics.geometry import Geometry
from ..kinematics.chain import inverse_kinematics
from ..uncertainty.model import linear_model
from ..kinematics.sensitivity import sensitivity

__all__ = ["Prediction", "predict", "NamedEffect", "Diagnosis", "DiscrepancyResult", "discrepancy",
           "detectable_effect"]

_Q_ALIAS = float(stats.chi2.ppf(0.99, 1))
_FACTOR_BOUNDS = (np.log(0.01), np.log(100.0))
_DEG = np.array([1.0, 1.0, 180.0 / np.pi])     # pose error rows [mm, mm, rad] -> [mm, mm, deg]
_DISPLAY = np.array([1e3, 1e3, 3600.0])        # [mm, mm, deg] -> [um, um, arcsec]
#: Largest contribution (mm or deg) of an effect at a generous magnitude below which it is invisible.
_INVISIBLE = 1e-9
_GENEROUS = {"mm": 1.0, "deg": 1.0, "1": 1e-2, "1/K": 1e-3}


# --------------------------------------------------------------------------- prediction
@dataclass(frozen=True, slots=True)
class Prediction:
    """Predicted distribution of ``measured - commanded`` at the measurements of a campaign.

    Attributes
    ----------
    mean : ndarray, shape (M, 3)
        Expected ``[dx mm, dy mm, dphi deg]`` per measurement (budget mean
        plus systematic effects, which may differ between repeats).
    cov : ndarray, shape (P, 3, 3)
        Covariance per commanded pose: budget plus instrument noise.
    pose_index : ndarray of int, shape (M,)
    budget : Budget
        The budget, with spread effects applied.
    effects : dict
        Systematic effects included, name -> value.
    """

    mean: np.ndarray
    cov: np.ndarray
    pose_index: np.ndarray
    budget: Budget
    effects: dict

    def to_frame(self) -> pd.DataFrame:
        """Per measurement: predicted mean and standard deviation, um and arcsec."""
        sd = np.sqrt(np.diagonal(self.cov, axis1=-2, axis2=-1))[self.pose_index]
        cols = {}
        for k, name in enumerate(("dx_um", "dy_um", "dphi_arcsec")):
            cols[f"mean_{name}"] = _DISPLAY[k] * self.mean[:, k]
            cols[f"sd_{name}"] = _DISPLAY[k] * sd[:, k]
        return pd.DataFrame({"pose": self.pose_index, **cols})


def _noise_cov(sigma_mm: float, sigma_deg: float) -> np.ndarray:
    for name, v in (("instrument_sigma_mm", sigma_mm), ("instrument_sigma_deg", sigma_deg)):
        if not (np.isfinite(v) and v >= 0):
            raise BudgetError(f"{name} must be finite and >= 0, got {v}")
    return np.diag([sigma_mm**2, sigma_mm**2, sigma_deg**2])


def predict(geometry: Geometry, budget: Budget, campaign: Campaign, *, effects: dict | None = None,
            instrument_sigma_mm: float = 0.0, instrument_sigma_deg: float = 0.0) -> Prediction:
    """Distribution of ``measured - commanded`` for every measurement of ``campaign``.

    Parameters
    ----------
    geometry, budget
    campaign : Campaign
    effects : dict of str to float, optional
        Library effects added to the model (systematic values and spreads).
    instrument_sigma_mm, instrument_sigma_deg : float

    Returns
    -------
    Prediction
    """
    effects = dict(effects or {})
    model_budget = spread_budget(budget, effects)
    mean, cov = linear_model(geometry, model_budget, campaign.poses, check=False).moments()
    cov = cov + _noise_cov(instrument_sigma_mm, instrument_sigma_deg)
    systematic = {k: v for k, v in effects.items() if effect(k).systematic}
    m = mean[campaign.pose_index]
    if systematic:
        G = signatures(geometry, campaign.poses, campaign.pose_index, list(systematic),
                       campaign.direction, campaign.temp_C)
        m = m + G @ np.array(list(systematic.values()))
    return Prediction(mean=m, cov=cov, pose_index=campaign.pose_index, budget=model_budget, effects=effects)


# --------------------------------------------------------------------------- engine
@dataclass(frozen=True, slots=True)
class _Fit:
    sys: tuple            # indices into _Engine.systematic
    factors: dict         # spread effect name -> factor on its input's bound
    theta: np.ndarray     # (k,)
    theta_cov: np.ndarray  # (k, k)
    loglik: float
    z: np.ndarray         # (M, 3) whitened residual after the fit
    resid: np.ndarray     # (M, 3) residual [mm, mm, deg] after the fit
    Gw: np.ndarray        # (M, 3, C) whitened signatures of every systematic candidate
    Linv: np.ndarray      # (P, 3, 3)
    k_between: float      # fitted dof taken from the pose means


class _Engine:
    """Arrays of one campaign under one budget; fits model states."""

    def __init__(self, geometry: Geometry, budget: Budget, campaign: Campaign, noise: np.ndarray):
        self.geometry, self.budget, self.campaign, self.noise = geometry, budget, campaign, noise
        self.idx = campaign.pose_index
        self.P, self.M = campaign.n_poses, campaign.n_measurements
        self.n = campaign.repeats.astype(float)
        self.err = campaign.error
        # per-input moment contributions: a spread scales them by (f, f^2)
        self.inputs = [k for k in budget.names if not k.startswith("zeta_")]
        mus, covs = [], []
        for name in self.inputs:
            laws = {name: budget.inputs[name]}
            if name.startswith("rho_"):
                laws["zeta" + name[3:]] = budget.inputs["zeta" + name[3:]]
            mu, cov = linear_model(geometry, Budget(laws), campaign.poses, check=False).moments()
            mus.append(mu)
            covs.append(cov)
        self.mu_k, self.cov_k = np.stack(mus), np.stack(covs)            # (I, P, 3), (I, P, 3, 3)
        base = self.cov_k.sum(0) + noise
        self.jitter = 1e-10 * np.trace(base, axis1=-2, axis2=-1)[:, None, None] * np.eye(3)
        lib = library(budget, campaign.has_dir, campaign.temp_C is not None)
        sys_effects = [e for e in lib if e.systematic]
        G = signatures(geometry, campaign.poses, self.idx, sys_effects, campaign.direction, campaign.temp_C)
        size = np.abs(G).max(axis=(0, 1)) * np.array([_GENEROUS[e.unit] for e in sys_effects])
        visible = size > _INVISIBLE
        self.invisible = tuple(e.name for e, v in zip(sys_effects, visible) if not v)
        self.systematic = [e for e, v in zip(sys_effects, visible) if v]
        self.G = G[:, :, visible]
        self.spreads = [e for e in lib if e.kind == "spread"]
        self.spread_input = {e.name: self.inputs.index(e.budget_input) for e in self.spreads}
        self.spread_ref = {e.name: spread_reference(budget, e) for e in self.spreads}
        self.not_testable = {e: f"needs {', '.join(effect(e).needs) or 'its budget input'}"
                             for e in EFFECT_NAMES if e not in {x.name for x in lib}}
        onehot = np.zeros((self.P, self.M))
        onehot[self.idx, np.arange(self.M)] = 1.0
        self.pose_mean_op = onehot / self.n[:, None]                      # (P, M)
        self.edges = _neighbour_edges(campaign.poses)
        self.b_pose, _ = inverse_kinematics(geometry, campaign.poses, check=False)   # (P, 3) mm
        self.Jb = sensitivity(geometry, campaign.poses, check=False).J["b"] * _DEG[:, None]  # (P, 3, 3)
        self.probes = _probe_basis(campaign, self.b_pose, self.Jb)

    # -- model moments
    def moments(self, factors: dict) -> tuple[np.ndarray, np.ndarray]:
        f = np.ones(len(self.inputs))
        for name, value in factors.items():
            f[self.spread_input[name]] = value
        mean = np.einsum("i,ipo->po", f, self.mu_k)
        cov = np.einsum("i,ipoq->poq", f**2, self.cov_k) + self.noise + self.jitter
        return mean, cov

    def fit(self, sys: tuple, factors: dict) -> _Fit:
        mean, cov = self.moments(factors)
        L = np.linalg.cholesky(cov)
        Linv = np.linalg.inv(L)
        Lm = Linv[self.idx]
        z0 = np.einsum("mij,mj->mi", Lm, self.err - mean[self.idx])
        Gw = np.einsum("mij,mjc->mic", Lm, self.G)
        logdet = 2.0 * np.log(np.diagonal(L, axis1=-2, axis2=-1)).sum(-1)[self.idx].sum()
        sys = tuple(sys)
        if sys:
            A = Gw[:, :, list(sys)].reshape(-1, len(sys))
            theta, *_ = np.linalg.lstsq(A, z0.ravel(), rcond=None)
            theta_cov = np.linalg.inv(A.T @ A)
            z = z0 - (A @ theta).reshape(-1, 3)
            resid = self.err - mean[self.idx] - self.G[:, :, list(sys)] @ theta
            Ab = np.einsum("pm,mic->pic", self.pose_mean_op, Gw[:, :, list(sys)])
            Ab = Ab * np.sqrt(self.n)[:, None, None]
            k_between = float(np.trace(theta_cov @ (Ab.reshape(-1, len(sys)).T @ Ab.reshape(-1, len(sys)))))
        else:
            theta, theta_cov, z, resid, k_between = np.zeros(0), np.zeros((0, 0)), z0, self.err - mean[self.idx], 0.0
        loglik = -0.5 * (float(np.sum(z * z)) + logdet + 3 * self.M * np.log(2 * np.pi))
        return _Fit(sys, dict(factors), theta, theta_cov, loglik, z, resid, Gw, Linv, k_between)

    def refit(self, sys: tuple, factors: dict) -> _Fit:
        """Maximum likelihood of the spread factors with the systematic values profiled out."""
        names = list(factors)
        if not names:
            return self.fit(sys, {})

        def nll(logf):
            return -self.fit(sys, dict(zip(names, np.exp(np.atleast_1d(logf))))).loglik

        x0 = np.log([factors[n] for n in names])
        if len(names) == 1:
            best = optimize.minimize_scalar(nll, bounds=_FACTOR_BOUNDS, method="bounded",
                                            options={"xatol": 1e-4})
            x = np.array([best.x])
        else:
            best = optimize.minimize(nll, x0, method="L-BFGS-B", bounds=[_FACTOR_BOUNDS] * len(names))
            x = best.x
        return self.fit(sys, dict(zip(names, np.exp(x))))

    # -- candidates
    def score_systematic(self, fit: _Fit) -> tuple[np.ndarray, np.ndarray]:
        """LR and estimate of adding each systematic candidate to ``fit`` (NaN if not testable)."""
        C = len(self.systematic)
        Gall = fit.Gw.reshape(-1, C)
        if fit.sys:
            Q, _ = np.linalg.qr(Gall[:, list(fit.sys)])
            Gp = Gall - Q @ (Q.T @ Gall)
        else:
            Gp = Gall
        den = np.sum(Gp * Gp, axis=0)
        num = Gp.T @ fit.z.ravel()
        ok = den > 1e-4 * np.sum(Gall * Gall, axis=0)   # >= 1 % of the signature outside the model
        ok[list(fit.sys)] = False
        est = np.where(ok, num / np.where(ok, den, 1.0), np.nan)
        lr = np.where(ok, num**2 / np.where(ok, den, 1.0), np.nan)
        backlash = np.array([e.kind == "backlash" for e in self.systematic])
        lr = np.where(backlash & (est < 0), 0.0, lr)       # h >= 0: constrained maximum at 0
        return lr, est

    def score_spread(self, fit: _Fit, name: str) -> tuple[float, _Fit]:
        trial = self.refit(fit.sys, {**fit.factors, name: 1.0})
        return 2.0 * (trial.loglik - fit.loglik), trial

    # -- intervals
    def spread_interval(self, fit: _Fit, name: str) -> tuple[float, float]:
        """Profile-likelihood 95 % interval of a spread factor (other spreads fixed)."""
        q = stats.chi2.ppf(0.95, 1)
        top = fit.loglik
        x_hat = np.log(fit.factors[name])

        def g(x):
            return 2.0 * (top - self.fit(fit.sys, {**fit.factors, name: np.exp(x)}).loglik) - q

        ends = []
        for bound in _FACTOR_BOUNDS:
            if g(bound) < 0:
                ends.append(bound)
            else:
                ends.append(optimize.brentq(g, min(x_hat, bound), max(x_hat, bound), xtol=1e-5))
        return float(np.exp(ends[0])), float(np.exp(ends[1]))

    def estimate(self, fit: _Fit, name: str) -> tuple[float, tuple[float, float]]:
        """Value and 95 % interval of effect ``name`` in ``fit``, in the effect's unit."""
        if name in fit.factors:
            ref = self.spread_ref[name]
            lo, hi = self.spread_interval(fit, name)
            return ref * fit.factors[name], (ref * lo, ref * hi)
        j = list(fit.sys).index(self.sys_index(name))
        value = float(fit.theta[j])
        half = 1.959963984540054 * float(np.sqrt(max(fit.theta_cov[j, j], 0.0)))
        if effect(name).kind == "backlash":          # h >= 0
            return max(value, 0.0), (max(value - half, 0.0), max(value + half, 0.0))
        return value, (value - half, value + half)

    def sys_index(self, name: str) -> int:
        return [e.name for e in self.systematic].index(name)

    def structural_aliases(self) -> list[list[str]]:
        """Groups of systematic candidates with (nearly) collinear whitened signatures."""
        Gw = self.fit((), {}).Gw.reshape(-1, len(self.systematic))
        norm = Gw / np.linalg.norm(Gw, axis=0)
        corr = np.abs(norm.T @ norm)
        groups, seen = [], set()
        for c in range(corr.shape[0]):
            if c in seen:
                continue
            members = [j for j in np.flatnonzero(corr[c] > 1 - 1e-6) if j not in seen]
            seen.update(members)
            if len(members) > 1:
                groups.append([self.systematic[j].name for j in members])
        return groups


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


def _probe_basis(campaign: Campaign, b_pose: np.ndarray, Jb: np.ndarray) -> np.ndarray:
    """Smooth lack-of-fit directions (M, 3, Q), [mm, mm, deg] per unit.

    Quadratic polynomials of the commanded pose for each output, cubic
    Legendre terms of each slider position along its J_b column, and a
    linear temperature trend per output: structure a missing effect outside
    the library is likely to leave behind.
    """
    c = campaign
    lo, span = c.poses.min(0), np.ptp(c.poses, axis=0)
    u = np.where(span > 0, 2.0 * (c.commanded - lo) / np.where(span > 0, span, 1.0) - 1.0, 0.0)
    ones = np.ones(c.n_measurements)
    terms = [ones, *u.T] + [u[:, a] * u[:, b] for a in range(3) for b in range(a, 3)]
    cols = [np.einsum("m,o->mo", t, np.eye(3)[o]) for t in terms for o in range(3)]
    if c.temp_C is not None:
        t = c.temp_C - c.temp_C.mean()
        cols += [np.einsum("m,o->mo", t, np.eye(3)[o]) for o in range(3)]
    bm = b_pose[c.pose_index]
    bspan = np.ptp(bm, axis=0)
    v = np.where(bspan > 0, 2.0 * (bm - bm.min(0)) / np.where(bspan > 0, bspan, 1.0) - 1.0, 0.0)
    for i in range(3):
        for poly in (0.5 * (3 * v[:, i] ** 2 - 1), 0.5 * (5 * v[:, i] ** 3 - 3 * v[:, i])):
            cols.append(Jb[c.pose_index][:, :, i] * poly[:, None])
    return np.stack(cols, axis=-1)


# --------------------------------------------------------------------------- diagnosis
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
        Per measurement: pose, residual (um, arcsec), whitened residual,
        slider positions ``b_1..3`` (mm), ``dir_1..3``, ``temp_C`` and the
        residual as an equivalent slider error ``db_eq_1..3_um`` (J_b^-1 r).
    summary : dict
        Global tests: ``sys_stat, sys_mean, sys_p``, ``disp_stat, disp_mean,
        disp_p, disp_direction``, ``gap, gap_null_sd``, per-pose Holm minima
        ``sys_holm_min, disp_holm_min``, flagged pose counts (BH 5 %).
    """

    poses: pd.DataFrame
    measurements: pd.DataFrame
    summary: dict


def _systematic_gap(engine: _Engine, fit: _Fit) -> tuple[float, float, int]:
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


def _null_variances(engine: _Engine, fit: _Fit, n_boot: int, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bootstrap variances (P,) of B_p, S_p and B_p + S_p under the fitted model."""
    bud = spread_budget(engine.budget, {n: f * engine.spread_ref[n] for n, f in fit.factors.items()})
    model = linear_model(engine.geometry, bud, engine.campaign.poses, check=False)
    mean, _ = engine.moments(fit.factors)
    X = bud.sample(n_boot * engine.M, rng)
    F = model.features(X).reshape(n_boot, engine.M, -1)
    e = np.einsum("mof,rmf->rmo", model.coef[engine.idx], F) * _DEG
    e += rng.standard_normal(e.shape) * np.sqrt(np.diagonal(engine.noise))
    z = np.einsum("mij,rmj->rmi", fit.Linv[engine.idx], e - mean[engine.idx])
    B, S = _pose_stats(engine, z)
    return B.var(0, ddof=1), S.var(0, ddof=1), (B + S).var(0, ddof=1)


def _pose_stats(engine: _Engine, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-pose systematic B_p and dispersion S_p of whitened residuals z (..., M, 3)."""
    zbar = np.einsum("pm,...mi->...pi", engine.pose_mean_op, z)
    B = engine.n * np.sum(zbar**2, axis=-1)
    total = np.einsum("pm,...m->...p", engine.pose_mean_op, np.sum(z**2, axis=-1)) * engine.n
    return B, total - B


def _lack_of_fit(engine: _Engine, fit: _Fit) -> dict:
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


def _diagnose(engine: _Engine, fit: _Fit, n_boot: int, rng) -> Diagnosis:
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
        meas[f"db_eq_{i + 1}_um"] = 1e3 * db[:, i]
    meas["temp_C"] = c.temp_C if c.temp_C is not None else np.nan
    return Diagnosis(poses=poses, measurements=meas, summary=summary)


# --------------------------------------------------------------------------- results
@dataclass(frozen=True, slots=True)
class NamedEffect:
    """An effect the workflow added to the model.

    Attributes
    ----------
    name : str
    value : float
        In ``unit`` (SPEC §5).
    unit : str
    ci95 : (float, float)
    aliases : tuple of str
        Effects the campaign cannot tell apart from this one; if any, the
        effect is *not* identified (one of the set is missing).
    evidence : dict
        ``lr, threshold, p_bonferroni, n_candidates, step, delta_bic,
        identified``, ``alias_fits`` (value and ci95 of each alias) and, for
        spreads, ``budget_value`` and ``direction``.
    """

    name: str
    value: float
    unit: str
    ci95: tuple
    aliases: tuple
    evidence: dict

    def to_dict(self) -> dict:
        return {"name": self.name, "value": self.value, "unit": self.unit, "ci95": list(self.ci95),
                "aliases": list(self.aliases), "evidence": self.evidence}


@dataclass(frozen=True, slots=True)
class DiscrepancyResult:
    """Outcome of :func:`discrepancy`.

    Attributes
    ----------
    named_effects : tuple of NamedEffect
        Empty when the model misses nothing the campaign can see.
    unexplained : bool
        Disagreement remains that no candidate explains.
    gap : dict
        ``metric, before, after, null_level, null_sd, closed`` and the two
        channels (see the module notes).
    before, after : Diagnosis
        Disagreement under the budget alone and with the named effects.
    steps : DataFrame
        Every candidate's LR at every selection step.
    prediction_after : Prediction
        The corrected model's prediction.
    budget_after : Budget
        The budget with named spreads applied.
    systematic : dict
        Named systematic effects, name -> value: the model's new parameters.
    invisible : tuple of str
        Effects whose signature vanishes over the campaign (never named).
    structural_aliases : tuple of tuple of str
        Groups of effects with collinear signatures over the campaign.
    not_testable : dict
        Effects the campaign cannot test, with the reason.
    seed, n_bootstrap : int
    alpha : float
    alpha_unexplained : float
    instrument_sigma_mm, instrument_sigma_deg : float
    version : str
    wall_time_s : float
    """

    named_effects: tuple
    unexplained: bool
    gap: dict
    before: Diagnosis
    after: Diagnosis
    steps: pd.DataFrame
    prediction_after: Prediction
    budget_after: Budget
    systematic: dict
    invisible: tuple
    structural_aliases: tuple
    not_testable: dict
    campaign: Campaign
    geometry: Geometry
    budget: Budget
    seed: int
    n_bootstrap: int
    alpha: float
    alpha_unexplained: float
    instrument_sigma_mm: float
    instrument_sigma_deg: float
    version: str = __version__
    wall_time_s: float = 0.0
    extra: dict = field(default_factory=dict)

    def to_frame(self) -> pd.DataFrame:
        """One row per named effect: name, value, unit, ci95_lo, ci95_hi, aliases, identified, lr."""
        return pd.DataFrame([{"name": e.name, "value": e.value, "unit": e.unit, "ci95_lo": e.ci95[0],
                              "ci95_hi": e.ci95[1], "aliases": ", ".join(e.aliases),
                              "identified": e.evidence["identified"], "lr": e.evidence["lr"]}
                             for e in self.named_effects],
                            columns=["name", "value", "unit", "ci95_lo", "ci95_hi", "aliases", "identified", "lr"])

    def to_dict(self) -> dict:
        """The ``discrepancy.json`` document of SPEC §6 (plus diagnostics)."""
        return {
            "named_effects": [e.to_dict() for e in self.named_effects],
            "unexplained": bool(self.unexplained),
            "gap": self.gap,
            "tests": {"before": self.before.summary, "after": self.after.summary},
            "invisible": list(self.invisible),
            "structural_aliases": [list(g) for g in self.structural_aliases],
            "not_testable": self.not_testable,
            "campaign": {"source": self.campaign.source, "n_measurements": self.campaign.n_measurements,
                         "n_poses": self.campaign.n_poses},
            "geometry": self.geometry.name, "budget": self.budget.name,
            "instrument_sigma_mm": self.instrument_sigma_mm, "instrument_sigma_deg": self.instrument_sigma_deg,
            "alpha": self.alpha, "alpha_unexplained": self.alpha_unexplained, "seed": self.seed, "n_bootstrap": self.n_bootstrap,
            "version": self.version, "wall_time_s": self.wall_time_s,
        }


# --------------------------------------------------------------------------- workflow
def _with(engine: _Engine, fit: _Fit, name: str) -> _Fit:
    """Refit ``fit``'s model with effect ``name`` added."""
    if effect(name).systematic:
        return engine.refit(fit.sys + (engine.sys_index(name),), fit.factors)
    return engine.refit(fit.sys, {**fit.factors, name: 1.0})


def _without(engine: _Engine, fit: _Fit, name: str) -> _Fit:
    if effect(name).systematic:
        j = engine.sys_index(name)
        return engine.refit(tuple(s for s in fit.sys if s != j), fit.factors)
    return engine.refit(fit.sys, {k: v for k, v in fit.factors.items() if k != name})


def _names_in(engine: _Engine, fit: _Fit) -> list[str]:
    return [engine.systematic[j].name for j in fit.sys] + list(fit.factors)


def _scan(engine: _Engine, fit: _Fit, excluded: set) -> pd.DataFrame:
    """LR and estimate of adding every testable candidate to ``fit``."""
    lr, est = engine.score_systematic(fit)
    rows = [{"candidate": e.name, "lr": float(lr[j]), "estimate": float(est[j])}
            for j, e in enumerate(engine.systematic) if np.isfinite(lr[j]) and e.name not in excluded]
    for e in engine.spreads:
        if e.name in fit.factors or e.name in excluded:
            continue
        value, trial = engine.score_spread(fit, e.name)
        rows.append({"candidate": e.name, "lr": max(value, 0.0),
                     "estimate": float(trial.factors[e.name] * engine.spread_ref[e.name])})
    return pd.DataFrame(rows, columns=["candidate", "lr", "estimate"])


def discrepancy(geometry: Geometry, budget: Budget, campaign, *, instrument_sigma_mm: float = 0.0,
                instrument_sigma_deg: float = 0.0, alpha: float = 0.01, alpha_unexplained: float = 0.05,
                max_effects: int = 6,
                n_bootstrap: int = 400,
                rng: "None | int | np.random.Generator" = None) -> DiscrepancyResult:
    """Find where model and campaign disagree, name the missing effects, close the gap.

    Parameters
    ----------
    geometry : Geometry
    budget : Budget
        The model's random errors.
    campaign : Campaign, DataFrame or path
        SPEC §4 campaign; validated against ``geometry``.
    instrument_sigma_mm, instrument_sigma_deg : float
        Standard deviation of the measurement noise per coordinate.
    alpha : float
        Family-wise level of the naming steps (Bonferroni over candidates).
    alpha_unexplained : float
        Family-wise level (Bonferroni over its six tests) of the final test
        for disagreement that the named effects leave unexplained. It is
        looser than ``alpha`` because declaring a gap closed when structure
        remains is the costlier error: on simulated campaigns (30 seeds each)
        it flagged every local distortion outside the library, 1 of 30
        correct models and none of 30 correctly named hidden effects.
    max_effects : int
        Most effects named.
    n_bootstrap : int
        Parametric-bootstrap replicates for the null variances of the tests.
    rng : None, int or numpy.random.Generator
        Randomness of the bootstrap (Scientific Python SPEC 7); the integer
        seed used is recorded in the result.

    Returns
    -------
    DiscrepancyResult
    """
    t0 = time.perf_counter()
    seed, rng = resolve_rng(rng)
    if not (0 < alpha < 1 and 0 < alpha_unexplained < 1):
        raise BudgetError(f"alpha and alpha_unexplained must lie in (0, 1), got {alpha}, {alpha_unexplained}")
    campaign = read_campaign(campaign, geometry)
    noise = _noise_cov(instrument_sigma_mm, instrument_sigma_deg)
    engine = _Engine(geometry, budget, campaign, noise)
    n_obs = 3 * engine.M
    base = engine.fit((), {})
    fit = base
    accepted: dict[str, dict] = {}        # name -> evidence of its acceptance
    excluded: set = set()
    step_rows = []
    for step in range(1, max_effects + 1):
        scan = _scan(engine, fit, excluded)
        if scan.empty:
            break
        K = len(scan)
        threshold = float(stats.chi2.isf(alpha / K, 1))
        scan = scan.assign(step=step, threshold=threshold, accepted=False).sort_values("lr", ascending=False)
        best = scan.iloc[0]
        passed = best["lr"] > threshold
        if passed:
            aliases = scan.loc[(scan["lr"] > best["lr"] - _Q_ALIAS) & (scan["candidate"] != best["candidate"]),
                               "candidate"].tolist()
            scan.loc[scan.index[0], "accepted"] = True
            p = float(stats.chi2.sf(best["lr"], 1))
            accepted[best["candidate"]] = {
                "lr": float(best["lr"]), "threshold": threshold, "p_bonferroni": min(1.0, K * p),
                "n_candidates": K, "step": step, "delta_bic": float(best["lr"] - np.log(n_obs)),
                "aliases": aliases,
            }
            excluded.update(aliases + [best["candidate"]])
            fit = _with(engine, fit, best["candidate"])
            for name in [n for n in _names_in(engine, fit) if n != best["candidate"]]:
                drop = 2.0 * (fit.loglik - _without(engine, fit, name).loglik)
                if drop < stats.chi2.isf(alpha, 1):
                    fit = _without(engine, fit, name)
                    accepted.pop(name)
        step_rows.append(scan)
        if not passed:
            break
    steps = pd.concat(step_rows, ignore_index=True) if step_rows else pd.DataFrame(
        columns=["candidate", "lr", "estimate", "step", "threshold", "accepted"])

    named = []
    for name in _names_in(engine, fit):
        ev = dict(accepted[name])
        aliases = ev.pop("aliases")
        value, ci = engine.estimate(fit, name)
        alias_fits = {}
        for alias in aliases:
            trial = _with(engine, _without(engine, fit, name), alias)
            a_value, a_ci = engine.estimate(trial, alias)
            alias_fits[alias] = {"value": a_value, "unit": effect(alias).unit, "ci95": list(a_ci)}
        ev.update(identified=not aliases, alias_fits=alias_fits)
        if name in fit.factors:
            ev.update(budget_value=engine.spread_ref[name],
                      direction="larger" if fit.factors[name] > 1 else "smaller")
        named.append(NamedEffect(name, float(value), effect(name).unit, (float(ci[0]), float(ci[1])),
                                 tuple(aliases), ev))

    before = _diagnose(engine, base, n_bootstrap, rng)
    after = _diagnose(engine, fit, n_bootstrap, rng)
    s = after.summary
    tests = ("sys_p", "disp_p", "sys_holm_min", "disp_holm_min", "spatial_p", "lack_of_fit_p")
    unexplained = bool(min(s[t] for t in tests) < alpha_unexplained / len(tests))
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
    closed = bool(not unexplained and residual_closed and g_after <= 5.0)
    gap = {
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
    systematic = {engine.systematic[j].name: float(v) for j, v in zip(fit.sys, fit.theta)}
    effects_after = {**systematic, **{n: f * engine.spread_ref[n] for n, f in fit.factors.items()}}
    prediction = predict(geometry, budget, campaign, effects=effects_after,
                         instrument_sigma_mm=instrument_sigma_mm, instrument_sigma_deg=instrument_sigma_deg)
    return DiscrepancyResult(
        named_effects=tuple(named), unexplained=unexplained, gap=gap, before=before, after=after, steps=steps,
        prediction_after=prediction, budget_after=prediction.budget, systematic=systematic,
        invisible=engine.invisible, structural_aliases=tuple(tuple(g) for g in engine.structural_aliases()),
        not_testable=engine.not_testable, campaign=campaign, geometry=geometry, budget=budget, seed=seed,
        n_bootstrap=n_bootstrap, alpha=alpha, alpha_unexplained=alpha_unexplained,
        instrument_sigma_mm=instrument_sigma_mm,
        instrument_sigma_deg=instrument_sigma_deg, wall_time_s=time.perf_counter() - t0)


def detectable_effect(geometry: Geometry, budget: Budget, campaign: Campaign, name: str, *,
                      power: float = 0.9, alpha: float = 0.01, instrument_sigma_mm: float = 0.0,
                      instrument_sigma_deg: float = 0.0) -> float:
    """Smallest |value| of a systematic effect that a campaign names with probability ``power``.

    For planning: simulate a campaign without effects (only its layout
    matters: poses, repeats, directions, temperatures) and ask how large an
    effect it would detect. Uses the non-central chi2(1) law of the LR at
    the Bonferroni threshold over the library's testable candidates;
    aliasing is not accounted for.

    Returns
    -------
    float
        In the effect's unit (SPEC §5); inf if the campaign cannot see it.
    """
    eff = effect(name)
    if not eff.systematic:
        raise BudgetError(f"{name}: detectable_effect handles systematic effects; simulate spreads instead")
    engine = _Engine(geometry, budget, read_campaign(campaign, geometry),
                     _noise_cov(instrument_sigma_mm, instrument_sigma_deg))
    if name not in [e.name for e in engine.systematic]:
        return float("inf")
    K = len(engine.systematic) + len(engine.spreads)
    threshold = stats.chi2.isf(alpha / K, 1)
    g = engine.fit((), {}).Gw[:, :, engine.sys_index(name)]
    info = float(np.sum(g * g))                                    # Fisher information per unit^2
    lam = optimize.brentq(lambda nc: stats.ncx2.sf(threshold, 1, nc) - power, 1e-6, 1e4)
    return float(np.sqrt(lam / info))
