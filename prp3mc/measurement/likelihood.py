"""The likelihood engine: fits of the model with and without library effects.

Inference uses the Gaussian likelihood of the residuals ``measured -
commanded - mu_p`` with covariance ``V_p = Sigma_p + N`` (see
:mod:`~prp3mc.measurement.prediction`); systematic values are generalized
least squares (exact covariance whatever the error law), a spread effect
scales one input's law about 0 so its contribution to ``(mu_p, Sigma_p)``
becomes ``(f mu_p, f^2 Sigma_p)`` and ``f`` is found by maximum likelihood
with a profile-likelihood interval.

:class:`Engine` holds the arrays of one campaign under one budget (per-input
moments, whitening, signatures of every visible systematic candidate, the
slider positions and J_b, the neighbour graph and the lack-of-fit probe
directions) and turns a model state (systematic effects in, spread factors)
into a :class:`Fit`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize, stats

from ..kinematics.chain import inverse_kinematics
from ..kinematics.geometry import Geometry
from ..kinematics.sensitivity import sensitivity
from ..uncertainty.budget import Budget
from ..uncertainty.model import linear_model
from ..units import z_value
from .campaign import Campaign
from .effects import EFFECT_NAMES, ROW_TO_DEG, effect, library, signatures, spread_reference

__all__ = ["Engine", "Fit"]

_FACTOR_BOUNDS = (np.log(0.01), np.log(100.0))
#: Largest contribution (mm or deg) of an effect at a generous magnitude below which it is invisible.
_INVISIBLE = 1e-9
_GENEROUS = {"mm": 1.0, "deg": 1.0, "1": 1e-2, "1/K": 1e-3}


@dataclass(frozen=True, slots=True)
class Fit:
    """One fitted model state of an :class:`Engine`."""

    sys: tuple            # indices into Engine.systematic
    factors: dict         # spread effect name -> factor on its input's bound
    theta: np.ndarray     # (k,)
    theta_cov: np.ndarray  # (k, k)
    loglik: float
    z: np.ndarray         # (M, 3) whitened residual after the fit
    resid: np.ndarray     # (M, 3) residual [mm, mm, deg] after the fit
    Gw: np.ndarray        # (M, 3, C) whitened signatures of every systematic candidate
    Linv: np.ndarray      # (P, 3, 3)
    k_between: float      # fitted dof taken from the pose means


class Engine:
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
        self.Jb = sensitivity(geometry, campaign.poses, check=False).J["b"] * ROW_TO_DEG[:, None]  # (P, 3, 3)
        self.probes = _probe_basis(campaign, self.b_pose, self.Jb)

    # -- model moments
    def moments(self, factors: dict) -> tuple[np.ndarray, np.ndarray]:
        """Model mean (P, 3) and covariance (P, 3, 3) with spread ``factors`` applied, noise included."""
        f = np.ones(len(self.inputs))
        for name, value in factors.items():
            f[self.spread_input[name]] = value
        mean = np.einsum("i,ipo->po", f, self.mu_k)
        cov = np.einsum("i,ipoq->poq", f**2, self.cov_k) + self.noise + self.jitter
        return mean, cov

    def fit(self, sys: tuple, factors: dict) -> Fit:
        """Fit of the systematic candidates ``sys`` (indices) at fixed spread ``factors``."""
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
        return Fit(sys, dict(factors), theta, theta_cov, loglik, z, resid, Gw, Linv, k_between)

    def refit(self, sys: tuple, factors: dict) -> Fit:
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
    def score_systematic(self, fit: Fit) -> tuple[np.ndarray, np.ndarray]:
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

    def score_spread(self, fit: Fit, name: str) -> tuple[float, Fit]:
        """LR of adding spread ``name`` to ``fit``, and the refitted state."""
        trial = self.refit(fit.sys, {**fit.factors, name: 1.0})
        return 2.0 * (trial.loglik - fit.loglik), trial

    # -- intervals
    def spread_interval(self, fit: Fit, name: str, level: float = 0.95) -> tuple[float, float]:
        """Profile-likelihood interval of a spread factor at ``level`` (other spreads fixed)."""
        q = stats.chi2.ppf(level, 1)
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

    def estimate(self, fit: Fit, name: str, level: float = 0.95) -> tuple[float, tuple[float, float]]:
        """Value and ``level`` confidence interval of effect ``name`` in ``fit``, in the effect's unit.

        Systematic values: Wald interval of the generalized least squares
        estimate (backlash clipped at 0); spreads: profile likelihood.
        """
        if name in fit.factors:
            ref = self.spread_ref[name]
            lo, hi = self.spread_interval(fit, name, level)
            return ref * fit.factors[name], (ref * lo, ref * hi)
        j = list(fit.sys).index(self.sys_index(name))
        value = float(fit.theta[j])
        half = z_value(level) * float(np.sqrt(max(fit.theta_cov[j, j], 0.0)))
        if effect(name).kind == "backlash":          # h >= 0
            return max(value, 0.0), (max(value - half, 0.0), max(value + half, 0.0))
        return value, (value - half, value + half)

    def sys_index(self, name: str) -> int:
        """Index of systematic candidate ``name`` in :attr:`systematic`."""
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
