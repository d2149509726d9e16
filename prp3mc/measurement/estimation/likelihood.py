"""The likelihood engine: fits of the model with and without library effects.

Measurement j of pose p is ``y = commanded + mu_p + H theta_n + G theta + u_p + w_j + n_j``
(:mod:`~prp3mc.measurement.forward.prediction`): the budget's mean ``mu_p``, the
nuisances (registration and drift, :mod:`~prp3mc.measurement.estimation.nuisance`),
systematic effects, and random errors whose budget covariance ``Sigma_p``
splits into a part ``u_p`` that repeats at every visit of the pose (``r
Sigma_p``) and a part ``w_j`` drawn afresh at each visit (``(1 - r)
Sigma_p``), plus instrument noise ``N``. With ``W_p = (1 - r) Sigma_p + N``,
the visits' deviations from their pose mean carry ``W_p`` and the pose mean
carries ``Vbar_p = r Sigma_p + W_p / n_p``. Whitening each part by its own
Cholesky factor turns the Gaussian likelihood into least squares: the
nuisances and the systematic values are generalized least squares (exact
covariance whatever the error laws), the repeatable fraction ``r`` and the
spread factors (a spread scales one input's law about 0, so its
contribution to ``(mu_p, Sigma_p)`` becomes ``(f mu_p, f^2 Sigma_p)``) are
found by maximum likelihood, with profile-likelihood intervals.

:class:`Engine` holds the arrays of one campaign (or of its rows kept after
setting outliers aside) under one budget; a model state (nuisances in,
systematic effects in, spread factors, ``r``) gives a :class:`Fit`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize

from ...kinematics.chain import inverse_kinematics
from ...kinematics.geometry import Geometry
from ...kinematics.sensitivity import sensitivity
from ...model.budget import Budget
from ...model.linear import linear_model
from ...units import z_value
from ..campaign.data import Campaign
from .cyclic import amplitude_interval
from ...model.effects import EffectKind
from ..forward.signatures import ROW_TO_DEG, budget_effect_errors, library, signatures, spread_reference, untestable
from .nuisance import DRIFT, NUISANCE_NAMES, NUISANCE_UNITS, REGISTRATION, campaign_time, nuisance_signatures
from .relinearise import Point

__all__ = ["Engine", "Fit", "subset_campaign", "chi2_equivalent"]

_FACTOR_BOUNDS = (np.log(0.01), np.log(100.0))
#: Largest contribution (mm or deg) of an effect at a generous magnitude below which it is invisible.
_INVISIBLE = 1e-9
_GENEROUS = {"mm": 1.0, "deg": 1.0, "1": 1e-2, "1/K": 1e-3}
#: Share of a signature's whitened energy that must lie outside the nuisance span for it to be testable.
CONFOUNDED = 1e-4


def chi2_equivalent(x, df, k=1):
    """The chi2(``k``) value with the upper tail of chi2(``df``) at ``x``: ``chi2.isf(chi2.sf(x, df), k)``.

    Puts likelihood ratios with different degrees of freedom on one scale (a
    two-parameter effect's LR on that of one-parameter effects) with their
    p-values kept. Far in the tail, where the p-value underflows, the
    chi-square tails' leading terms ``-x/2 + (df/2 - 1) log(x/2) - lgamma(df/2)``
    are equated instead (monotone in ``x``). Identity when ``df == k``.
    """
    from scipy.special import gammaln
    from scipy.stats import chi2  # imported when used: prp3mc --help imports this module
    x, df, k = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(df, dtype=np.float64),
                                   np.asarray(k, dtype=np.float64))
    out = np.array(x, dtype=np.float64, copy=True)
    todo = (df != k) & (x > 0)
    if todo.any():
        xs, d, kk = x[todo], df[todo], k[todo]
        logp = np.asarray(chi2.logsf(xs, d), dtype=np.float64)
        y = np.empty_like(xs)
        near = logp > -600.0
        y[near] = chi2.isf(np.exp(logp[near]), kk[near])
        far = ~near
        if far.any():
            target = -xs[far] / 2 + (d[far] / 2 - 1) * np.log(xs[far] / 2) - gammaln(d[far] / 2) + gammaln(kk[far] / 2)
            yf = xs[far].copy()
            for _ in range(4):                       # y = -2 target + (k - 2) log(y / 2), a contraction here
                yf = -2.0 * target + (kk[far] - 2.0) * np.log(yf / 2.0)
            y[far] = yf
        out[todo] = y
    return out[()] if out.ndim == 0 else out


@dataclass(frozen=True, slots=True)
class Fit:
    """One fitted model state of an :class:`Engine`.

    ``theta`` holds the nuisance values (those of ``nuis``) then the
    systematic values (those of ``sys``, each effect's
    :attr:`~prp3mc.model.effects.Effect.dof` of them: a cyclic
    error's phasor as its real and imaginary parts); ``z`` is the whitened residual
    (3M within rows, then 3P between rows), ``zw`` (M, 3) and ``zb`` (P, 3)
    its two parts (``zb``: standardised pose means).
    """

    sys: tuple            # indices into Engine.systematic
    factors: dict         # spread effect name -> factor on its input's bound
    r: float              # repeatable fraction
    nuis: tuple           # indices into NUISANCE_NAMES
    theta: np.ndarray     # (n_nuis + k,)
    theta_cov: np.ndarray
    loglik: float
    z: np.ndarray         # (3M + 3P,)
    resid: np.ndarray     # (M, 3) residual [mm, mm, deg] after the fit
    Lw: np.ndarray        # (P, 3, 3) whitening matrix of W_p (Lw' Lw = W_p^-1)
    Lb: np.ndarray        # (P, 3, 3) whitening matrix of Vbar_p
    k_between: float      # fitted dof taken from the pose means

    @property
    def zw(self) -> np.ndarray:
        return self.z[:self.resid.size].reshape(-1, 3)

    @property
    def zb(self) -> np.ndarray:
        return self.z[self.resid.size:].reshape(-1, 3)


def subset_campaign(campaign: Campaign, keep: np.ndarray) -> Campaign:
    """The rows ``keep`` (bool, shape (M,)) of ``campaign``; poses left without rows are dropped."""
    kept_poses = np.unique(campaign.pose_index[keep])
    remap = np.full(campaign.n_poses, -1)
    remap[kept_poses] = np.arange(kept_poses.size)
    return Campaign(
        pose_id=campaign.pose_id[keep], commanded=campaign.commanded[keep], measured=campaign.measured[keep],
        direction=campaign.direction[keep], has_dir=campaign.has_dir,
        temp_C=None if campaign.temp_C is None else campaign.temp_C[keep],
        extra=campaign.extra[keep].reset_index(drop=True), poses=campaign.poses[kept_poses],
        pose_labels=tuple(campaign.pose_labels[p] for p in kept_poses),
        pose_index=remap[campaign.pose_index[keep]], source=campaign.source, metadata=campaign.metadata)


class Engine:
    """Arrays of one campaign under one budget; fits model states.

    Systematic candidates (:attr:`systematic`) have one signature column
    each in :attr:`G`, but a cyclic screw error two (its phasor's parts):
    :attr:`blocks` maps each candidate to its columns. Likelihood ratios of
    candidates are put on the chi2(1) scale (:func:`~prp3mc.measurement.estimation.likelihood.chi2_equivalent`),
    so that every test compares them with one threshold at their own p-value.

    Parameters
    ----------
    geometry, budget, campaign
    noise : ndarray, shape (3, 3)
        Instrument noise covariance.
    registration : bool
        Fit the instrument's registration (else the campaign is taken as registered).
    keep : ndarray of bool, shape (M,), optional
        Rows used (outliers set aside); time and row numbers stay those of the whole campaign.
    point : Point, optional
        The exact chain linearised about an estimate of the systematic
        effects (:mod:`~prp3mc.measurement.estimation.relinearise`): the model's known
        pose error, the candidates' signatures and the budget's moments are
        taken there. By default the model is linear about the nominal geometry.
    """

    def __init__(self, geometry: Geometry, budget: Budget, campaign: Campaign, noise: np.ndarray, *,
                 registration: bool = True, keep: np.ndarray | None = None, point: Point | None = None):
        self.geometry, self.budget, self.noise, self.registration = geometry, budget, noise, registration
        self.full_campaign, self.point = campaign, point
        s, self.time_source = campaign_time(campaign)
        keep = np.ones(campaign.n_measurements, bool) if keep is None else np.asarray(keep, bool)
        self.keep, self.rows = keep, np.flatnonzero(keep)
        kept_poses = np.unique(campaign.pose_index[keep])
        campaign = campaign if keep.all() else subset_campaign(campaign, keep)
        self.campaign = campaign
        self.idx = campaign.pose_index
        self.P, self.M = campaign.n_poses, campaign.n_measurements
        self.n = campaign.repeats.astype(float)
        #: the machine the budget's moments are taken at: its geometry and the poses it reaches (P, 3)
        self.model_geometry, self.model_poses = ((geometry, campaign.poses) if point is None else
                                                 (point.geometry, point.poses[kept_poses]))
        #: (M, 3) pose errors of the budget's [effects] (their drivers from the campaign): part of every model
        self.known = budget_effect_errors(geometry, budget, campaign) if point is None else point.known[keep]
        self.err = campaign.error - self.known
        # per-input moment contributions: a spread scales them by (f, f^2)
        self.inputs = [k for k in budget.names if not k.startswith("zeta_")]
        mus, covs = [], []
        for name in self.inputs:
            laws = {name: budget.inputs[name]}
            if name.startswith("rho_"):
                laws["zeta" + name[3:]] = budget.inputs["zeta" + name[3:]]
            mu, cov = linear_model(self.model_geometry, Budget(laws), self.model_poses, check=False).moments()
            mus.append(mu)
            covs.append(cov)
        self.mu_k, self.cov_k = np.stack(mus), np.stack(covs)            # (I, P, 3), (I, P, 3, 3)
        base = self.cov_k.sum(0) + noise
        self.jitter = 1e-10 * np.trace(base, axis1=-2, axis2=-1)[:, None, None] * np.eye(3)
        self.H = nuisance_signatures(campaign.commanded, s[keep])
        self.nuisance = tuple(j for j, name in enumerate(NUISANCE_NAMES)
                              if name in DRIFT or (registration and name in REGISTRATION))
        #: whether some pose is measured twice: without, the dispersion channels (spreads, r) are not testable
        self.repeats = bool((campaign.repeats >= 2).any())
        has_lead = tuple(bool(np.isfinite(p)) for p in geometry.lead_mm)
        reach = (budget, campaign.has_dir, campaign.temp_C is not None, has_lead, self.repeats)
        lib = library(*reach)
        sys_effects = [e for e in lib if e.systematic]
        G = (signatures(geometry, campaign.poses, self.idx, sys_effects, campaign.direction, campaign.temp_C)
             if point is None else point.signatures([e.name for e in sys_effects])[keep])
        owner = np.repeat(np.arange(len(sys_effects)), [e.dof for e in sys_effects])       # candidate of each column
        size = np.zeros(len(sys_effects))
        np.maximum.at(size, owner, np.abs(G).max(axis=(0, 1)))
        visible = size * np.array([_GENEROUS[e.unit] for e in sys_effects]) > _INVISIBLE
        self.invisible = tuple(e.name for e, v in zip(sys_effects, visible) if not v)
        self.systematic = [e for e, v in zip(sys_effects, visible) if v]
        self.G = G[:, :, visible[owner]]
        dof = [e.dof for e in self.systematic]
        #: columns of G of each candidate
        self.blocks = tuple(np.arange(start, start + k) for start, k in zip(np.cumsum([0] + dof[:-1]), dof))
        # least value of each column: a backlash width h >= 0, so its correction to a budget's h is >= -h
        self.lower = np.array([(-budget.effects[e.name].value if e.name in budget.effects else 0.0)
                               if e.kind is EffectKind.BACKLASH else -np.inf
                               for e in self.systematic for _ in range(e.dof)])
        self.spreads = [e for e in lib if not e.systematic]
        self.spread_input = {e.name: self.inputs.index(e.budget_input) for e in self.spreads}
        self.spread_ref = {e.name: spread_reference(budget, e) for e in self.spreads}
        self.not_testable = untestable(*reach)
        self._order = np.argsort(self.idx, kind="stable")
        self._starts = np.concatenate([[0], np.cumsum(campaign.repeats)[:-1]])
        self.b_pose, _ = inverse_kinematics(geometry, campaign.poses, check=False)   # (P, 3) mm
        self.Jb = sensitivity(geometry, campaign.poses, check=False).J["b"] * ROW_TO_DEG[:, None]  # (P, 3, 3)
        self._cache: dict = {}                            # spread factors -> basis (see _basis)
        self._centred_cache: dict = {}                    # columns -> centred signatures (see _centred)
        C = np.linalg.cholesky(noise + self.jitter)      # the same for every model state: factorised once
        self._noise_factor = (np.linalg.inv(C), 2.0 * np.log(np.diagonal(C, axis1=-2, axis2=-1)).sum(-1))
        self.confounded = self._confounded()

    def with_rows(self, keep: np.ndarray) -> "Engine":
        """The engine of the rows ``keep`` (bool, shape (M,) of the whole campaign) at the same point."""
        if np.array_equal(keep, self.keep):
            return self
        return Engine(self.geometry, self.budget, self.full_campaign, self.noise, registration=self.registration,
                      keep=keep, point=self.point)

    def cols_of(self, sys: tuple) -> list[int]:
        """Columns of :attr:`G` of the candidates ``sys`` (indices into :attr:`systematic`), in order."""
        return [int(c) for j in sys for c in self.blocks[j]]

    def dof(self, sys: tuple) -> int:
        """Parameters of the candidates ``sys``: their columns' count."""
        return sum(len(self.blocks[j]) for j in sys)

    # -- model moments and whitening
    def moments(self, factors: dict, r: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Budget mean (P, 3), within-pose covariance W (P, 3, 3) and repeatable covariance r Sigma (P, 3, 3)."""
        mean, sigma = self._sigma(factors)
        return mean, (1.0 - r) * sigma + self.noise + self.jitter, r * sigma

    def _sigma(self, factors: dict) -> tuple[np.ndarray, np.ndarray]:
        f = np.ones(len(self.inputs))
        for name, value in factors.items():
            f[self.spread_input[name]] = value
        return np.einsum("i,ipo->po", f, self.mu_k), np.einsum("i,ipoq->poq", f**2, self.cov_k)

    def _basis(self, factors: dict) -> dict:
        """Per-pose basis that diagonalises Sigma_p and N at once, and the data and signatures in it.

        With ``V' N V = I`` and ``V' Sigma V = diag(lam)``, ``W`` and
        ``Vbar`` are diagonal in it for every ``r``: ``(1 - r) lam + 1`` and
        ``r lam + ((1 - r) lam + 1) / n``, so a new ``r`` only rescales.
        """
        key = tuple(sorted(factors.items()))
        cached = self._cache.get(key)
        if cached is not None:
            return cached
        mean, sigma = self._sigma(factors)
        Ci, logdet_noise = self._noise_factor
        lam, U = np.linalg.eigh(Ci @ sigma @ np.swapaxes(Ci, 1, 2))
        Vt = np.swapaxes(U, 1, 2) @ Ci                                     # (P, 3, 3): V'
        y = self.err - mean[self.idx]
        ybar = self.pose_mean(y)
        Vm = Vt[self.idx]
        basis = {"mean": mean, "lam": np.maximum(lam, 0.0), "Vt": Vt, "Vm": Vm,
                 "logdet_noise": logdet_noise,
                 "yw": np.einsum("mij,mj->mi", Vm, y - ybar[self.idx]), "yb": np.einsum("pij,pj->pi", Vt, ybar)}
        if len(self._cache) > 64:
            self._cache.clear()
        self._cache[key] = basis
        return basis

    def _scales(self, basis: dict, r: float) -> tuple[np.ndarray, np.ndarray, float]:
        """Whitening scales (P, 3) of the within and between parts at ``r``, and the log-determinant term."""
        dw = (1.0 - r) * basis["lam"] + 1.0
        db = r * basis["lam"] + dw / self.n[:, None]
        ld = basis["logdet_noise"]
        logdet = np.sum((self.n - 1.0) * (np.log(dw).sum(-1) + ld) + np.log(db).sum(-1) + ld + 3.0 * np.log(self.n))
        return 1.0 / np.sqrt(dw), 1.0 / np.sqrt(db), float(logdet)

    def pose_mean(self, X: np.ndarray, axis: int = 0) -> np.ndarray:
        """Mean over each pose's measurements along ``axis`` (of length M) of X: that axis becomes P."""
        sums = np.add.reduceat(np.take(X, self._order, axis=axis), self._starts, axis=axis)
        shape = [1] * X.ndim
        shape[axis] = self.P
        return sums / self.n.reshape(shape)

    def whiten(self, X: np.ndarray, Lw: np.ndarray, Lb: np.ndarray) -> np.ndarray:
        """Whitened rows of per-measurement pose errors X (M, 3[, K]): (3M + 3P[, K])."""
        tail = X.shape[2:]
        X3 = X.reshape(self.M, 3, -1)
        Xbar = self.pose_mean(X3)                                           # (P, 3, K)
        within = Lw[self.idx] @ (X3 - Xbar[self.idx])
        between = Lb @ Xbar
        return np.concatenate([within.reshape(-1, *tail), between.reshape(-1, *tail)])

    def _stacked(self, basis: dict, sw: np.ndarray, sb: np.ndarray, cols: list) -> tuple[np.ndarray, np.ndarray]:
        """Whitened residual (3M + 3P,) and signature columns ``cols`` (3M + 3P, k) from a basis and scales.

        ``cols`` index the nuisance signatures, then the systematic candidates.
        """
        swm = sw[self.idx]
        z0 = np.concatenate([(basis["yw"] * swm).ravel(), (basis["yb"] * sb).ravel()])
        stacks = basis.setdefault("stacks", {})             # columns -> their (within, between) parts, stacked
        if tuple(cols) not in stacks:
            projected = basis.setdefault("columns", {})     # column -> its (within, between) parts in the basis
            missing = tuple(c for c in dict.fromkeys(cols) if c not in projected)
            if missing:
                centred, Xbar = self._centred(missing)
                cw, cb = basis["Vm"] @ centred, basis["Vt"] @ Xbar
                for k, c in enumerate(missing):
                    projected[c] = (cw[:, :, k], cb[:, :, k])
            stacks[tuple(cols)] = (
                np.stack([projected[c][0] for c in cols], axis=2) if cols else np.zeros((self.M, 3, 0)),
                np.stack([projected[c][1] for c in cols], axis=2) if cols else np.zeros((self.P, 3, 0)))
        cw, cb = stacks[tuple(cols)]
        A = np.concatenate([(cw * swm[..., None]).reshape(3 * self.M, len(cols)),
                            (cb * sb[..., None]).reshape(3 * self.P, len(cols))])
        return z0, A

    def _centred(self, cols: tuple) -> tuple[np.ndarray, np.ndarray]:
        """Signatures ``cols`` (nuisance columns, then candidates offset by the nuisances' count) less their pose
        means, (M, 3, k), and those means, (P, 3, k): the same in every basis, computed once."""
        if cols not in self._centred_cache:
            nH = self.H.shape[2]
            X = np.stack([self.H[:, :, c] if c < nH else self.G[:, :, c - nH] for c in cols], axis=2)
            Xbar = self.pose_mean(X)
            self._centred_cache[cols] = (X - Xbar[self.idx], Xbar)
        return self._centred_cache[cols]

    def columns(self, sys: tuple, nuis: tuple | None = None) -> np.ndarray:
        """Signatures (M, 3, n_nuis + k) of the nuisances ``nuis`` (all fitted ones if None), then ``sys``."""
        nuis = self.nuisance if nuis is None else nuis
        return np.concatenate([self.H[:, :, list(nuis)], self.G[:, :, self.cols_of(sys)]], axis=2)

    def _solve(self, sys: tuple, factors: dict, r: float, nuis: tuple | None) -> tuple:
        """The generalized least squares of a model state: ``sys, nuis, basis, sw, sb, A, theta, theta_cov, z,
        loglik`` (what :meth:`fit` returns, before the parts only a :class:`Fit` carries)."""
        nuis = self.nuisance if nuis is None else tuple(nuis)
        sys = tuple(sys)
        basis = self._basis(factors)
        sw, sb, logdet = self._scales(basis, r)
        cols = list(nuis) + [self.H.shape[2] + c for c in self.cols_of(sys)]
        z0, A = self._stacked(basis, sw, sb, cols)
        if cols:
            theta_cov = np.linalg.pinv(A.T @ A)
            theta = theta_cov @ (A.T @ z0)
            z = z0 - A @ theta
        else:
            theta, theta_cov, z = np.zeros(0), np.zeros((0, 0)), z0
        loglik = -0.5 * (float(z @ z) + logdet + 3 * self.M * np.log(2 * np.pi))
        return sys, nuis, basis, sw, sb, A, theta, theta_cov, z, loglik

    def loglik(self, sys: tuple, factors: dict, r: float, nuis: tuple | None = None) -> float:
        """Log-likelihood of :meth:`fit`'s model state alone (what the optimisers evaluate)."""
        return self._solve(sys, factors, r, nuis)[-1]

    def fit(self, sys: tuple, factors: dict, r: float, nuis: tuple | None = None) -> Fit:
        """Fit of the systematic candidates ``sys`` (indices) at fixed spread ``factors`` and ``r``."""
        sys, nuis, basis, sw, sb, A, theta, theta_cov, z, loglik = self._solve(sys, factors, r, nuis)
        resid = self.err - basis["mean"][self.idx]
        k_between = 0.0
        if theta.size:
            Ab = A[3 * self.M:]
            k_between = float(np.trace(theta_cov @ (Ab.T @ Ab)))
            resid = resid - self.columns(sys, nuis) @ theta
        Lw = sw[:, :, None] * basis["Vt"]
        Lb = sb[:, :, None] * basis["Vt"]
        return Fit(sys, dict(factors), float(r), nuis, theta, theta_cov, loglik, z, resid, Lw, Lb, k_between)

    def refit(self, sys: tuple, factors: dict, r: float | None = None, start_r: float = 0.5,
              nuis: tuple | None = None, free: tuple | None = None) -> Fit:
        """Maximum likelihood of the spread factors and (if ``r`` is None) of ``r``, values profiled out.

        ``free`` names the spread factors optimised (all by default); the
        others stay at their value in ``factors``. Without repeats ``r`` does
        not change the likelihood (every pose mean has ``Sigma + N``): it is 0.
        """
        names = list(factors) if free is None else list(free)
        if r is None and not self.repeats:
            r = 0.0
        free_r = r is None

        def state(x):
            x = np.atleast_1d(x)
            f = {**factors, **dict(zip(names, np.exp(x[:len(names)])))}
            return f, (float(x[-1]) if free_r else r)

        def nll(x):
            f, rr = state(x)
            return -self.loglik(sys, f, rr, nuis)

        x0 = [np.log(factors[n]) for n in names] + ([start_r] if free_r else [])
        bounds = [_FACTOR_BOUNDS] * len(names) + ([(0.0, 1.0)] if free_r else [])
        if not x0:
            return self.fit(sys, factors, r, nuis)
        if len(x0) == 1:
            best = optimize.minimize_scalar(nll, bounds=bounds[0], method="bounded", options={"xatol": 1e-3})
            x = np.array([best.x])
            for end in bounds[0]:                         # the bounded method never evaluates the ends
                if nll(end) < best.fun:
                    x = np.array([end])
        else:
            x = optimize.minimize(nll, np.array(x0, float), method="L-BFGS-B", bounds=bounds).x
        f, rr = state(x)
        return self.fit(sys, f, rr, nuis)

    # -- candidates
    def whitened(self, fit: Fit, sys: tuple = (), nuis: tuple = ()) -> tuple[np.ndarray, np.ndarray]:
        """Whitened error before any value is fitted (3M + 3P,) and signatures of ``nuis`` then ``sys``
        (3M + 3P, k), at ``fit``'s covariance."""
        basis = self._basis(fit.factors)
        sw, sb, _ = self._scales(basis, fit.r)
        return self._stacked(basis, sw, sb, list(nuis) + [self.H.shape[2] + c for c in self.cols_of(sys)])

    def whitened_candidates(self, fit: Fit) -> np.ndarray:
        """Whitened signature columns of every systematic candidate at ``fit``'s covariance, (3M + 3P, C)
        (candidate j's are ``blocks[j]``)."""
        return self.whitened(fit, tuple(range(len(self.systematic))))[1]

    def kept_share(self, A: np.ndarray, rest: np.ndarray) -> np.ndarray:
        """Per candidate, the least share of a combination of its columns' energy (``A``) that ``rest`` keeps.

        ``rest`` is ``A`` with a span projected out; for a one-column candidate
        the share is ``|rest|^2 / |A|^2``, for a block the smallest generalized
        eigenvalue of ``(rest' rest, A' A)``.
        """
        first = np.array([cols[0] for cols in self.blocks], dtype=int)
        total, kept = np.sum(A[:, first] ** 2, axis=0), np.sum(rest[:, first] ** 2, axis=0)
        out = np.where(total > 0, kept / np.where(total > 0, total, 1.0), 0.0)
        for j in (j for j, cols in enumerate(self.blocks) if len(cols) > 1):
            a, r = A[:, self.blocks[j]], rest[:, self.blocks[j]]
            w, U = np.linalg.eigh(a.T @ a)
            if not w[0] > 1e-300:
                out[j] = 0.0
                continue
            T = U / np.sqrt(w)                             # whitens A' A
            out[j] = float(np.linalg.eigvalsh(T.T @ (r.T @ r) @ T)[0])
        return out

    def _confounded(self) -> dict:
        """Candidates whose whitened signature lies (almost) in the nuisance span, name -> what with."""
        fit = self.fit((), {}, 0.0)
        A = self.whitened_candidates(fit)
        out = {}
        X = self.whitened(fit, (), tuple(range(self.H.shape[2])))[1]
        spans = {"registration": [j for j in self.nuisance if NUISANCE_NAMES[j] in REGISTRATION],
                 "drift": [j for j in self.nuisance if NUISANCE_NAMES[j] in DRIFT]}
        spans["registration and drift"] = list(self.nuisance)
        for label, cols in spans.items():
            if not cols:
                continue
            Q, _ = np.linalg.qr(X[:, cols])
            rest = A - Q @ (Q.T @ A)
            for j in np.flatnonzero(self.kept_share(A, rest) < CONFOUNDED):
                out.setdefault(self.systematic[j].name, label)
        return out

    def score_systematic(self, fit: Fit) -> tuple[np.ndarray, np.ndarray]:
        """LR (on the chi2(1) scale) and estimate of adding each systematic candidate to ``fit`` at its
        covariance (NaN if not testable); a cyclic error's estimate is its amplitude."""
        Gall = self.whitened_candidates(fit)
        X = self.whitened(fit, fit.sys, fit.nuis)[1]
        if X.shape[1]:
            Q, _ = np.linalg.qr(X)
            Gp = Gall - Q @ (Q.T @ Gall)
        else:
            Gp = Gall
        den = np.sum(Gp * Gp, axis=0)
        num = Gp.T @ fit.z
        ok = self.kept_share(Gall, Gp) > CONFOUNDED
        ok[list(fit.sys)] = False
        ok &= np.array([e.name not in self.confounded for e in self.systematic], bool)
        first = np.array([cols[0] for cols in self.blocks], dtype=int)
        den1, num1, lower = den[first], num[first], self.lower[first]
        est = np.where(ok, num1 / np.where(ok, den1, 1.0), np.nan)
        lr = np.where(ok, num1**2 / np.where(ok, den1, 1.0), np.nan)
        # below its least value (h >= 0) the constrained maximum is at that value
        low = np.where(np.isfinite(lower), lower, 0.0)
        lr = np.where(est < lower, den1 * low * (2.0 * est - low), lr)
        for j in np.flatnonzero(ok & np.array([len(c) > 1 for c in self.blocks])):
            cols = self.blocks[j]
            theta = np.linalg.solve(Gp[:, cols].T @ Gp[:, cols], num[cols])
            lr[j] = float(chi2_equivalent(theta @ num[cols], len(cols)))
            est[j] = float(np.hypot(*theta))
        return lr, est

    # -- intervals
    def _profile_interval(self, loglik, x_hat: float, lo: float, hi: float, level: float) -> tuple[float, float]:
        """Ends of {x: 2 (max - loglik(x)) <= chi2_1(level)} within [lo, hi], by root finding."""
        from scipy.stats import chi2  # imported when used: prp3mc --help imports this module
        q = chi2.ppf(level, 1)
        top = loglik(x_hat)

        def g(x):
            return 2.0 * (top - loglik(x)) - q

        ends = []
        for bound in (lo, hi):
            if bound == x_hat or g(bound) < 0:
                ends.append(bound)
            else:
                ends.append(optimize.brentq(g, min(x_hat, bound), max(x_hat, bound), xtol=1e-5))
        return float(ends[0]), float(ends[1])

    def spread_interval(self, fit: Fit, name: str, level: float = 0.95) -> tuple[float, float]:
        """Profile-likelihood interval of a spread factor at ``level`` (other spreads and r fixed)."""
        def ll(x):
            return self.loglik(fit.sys, {**fit.factors, name: np.exp(x)}, fit.r, fit.nuis)
        lo, hi = self._profile_interval(ll, np.log(fit.factors[name]), *_FACTOR_BOUNDS, level)
        return float(np.exp(lo)), float(np.exp(hi))

    def r_interval(self, fit: Fit, level: float = 0.95) -> tuple[float, float]:
        """Profile-likelihood interval of the repeatable fraction (spread factors fixed)."""
        return self._profile_interval(lambda r: self.loglik(fit.sys, fit.factors, r, fit.nuis),
                                      fit.r, 0.0, 1.0, level)

    def wald(self, fit: Fit, j: int, level: float = 0.95) -> tuple[float, tuple[float, float]]:
        """Value and Wald interval of ``fit.theta[j]``."""
        value = float(fit.theta[j])
        half = z_value(level) * float(np.sqrt(max(fit.theta_cov[j, j], 0.0)))
        return value, (value - half, value + half)

    def _theta_of(self, fit: Fit, name: str) -> np.ndarray:
        """Indices into ``fit.theta`` of systematic effect ``name``'s values."""
        j = self.sys_index(name)
        start = len(fit.nuis) + self.dof(fit.sys[:list(fit.sys).index(j)])
        return np.arange(start, start + len(self.blocks[j]))

    def phasor(self, fit: Fit, name: str, offset: complex = 0j, level: float = 0.95) -> dict:
        """A cyclic error of ``fit``: its phasor (with ``offset`` added: a budget's value it corrects),
        amplitude and phase, the amplitude's interval (:func:`~prp3mc.measurement.estimation.cyclic.amplitude_interval`)
        and the phasor's covariance (mm^2)."""
        k = self._theta_of(fit, name)
        c = fit.theta[k] + np.array([offset.real, offset.imag])
        V = fit.theta_cov[np.ix_(k, k)]
        z = complex(c[0], c[1])
        return {"phasor": z, "amplitude": abs(z), "phase_deg": float(np.rad2deg(np.angle(z)) % 360.0),
                "ci": amplitude_interval(c, V, level), "cov": V}

    def nuisances(self, fit: Fit, level: float = 0.95) -> dict:
        """The nuisances of ``fit``, name -> ``{value, unit, ci95}`` at ``level``.

        Wald intervals of the generalized least squares, widened by the
        uncertainty of the spread factors: a spread scales its input's mean
        too (a one-sided encoder law's mean moves with its bound), which the
        registration partly takes up. Each factor's standard error on the log
        scale (from its profile interval) times the nuisances' derivative in
        it (central difference over that standard error) adds in quadrature.
        """
        var = np.clip(np.diagonal(fit.theta_cov)[:len(fit.nuis)], 0.0, None).copy()
        for name, f in fit.factors.items():
            lo, hi = self.spread_interval(fit, name)
            se = (np.log(hi) - np.log(lo)) / (2.0 * z_value(0.95))
            if not se > 0:
                continue
            ends = [self.fit(fit.sys, {**fit.factors, name: f * np.exp(d)}, fit.r, fit.nuis).theta[:len(fit.nuis)]
                    for d in (se, -se)]
            var += (0.5 * (ends[0] - ends[1])) ** 2
        half = z_value(level) * np.sqrt(var)
        out = {}
        for j, col in enumerate(fit.nuis):
            name = NUISANCE_NAMES[col]
            value = float(fit.theta[j])
            out[name] = {"value": value, "unit": NUISANCE_UNITS[name],
                         "ci95": [value - float(half[j]), value + float(half[j])]}
        return out

    def estimate(self, fit: Fit, name: str, level: float = 0.95) -> tuple[float, tuple[float, float]]:
        """Value and ``level`` confidence interval of effect ``name`` in ``fit``, in the effect's unit.

        Systematic values: Wald interval of the generalized least squares
        estimate (a backlash clipped at its least value, :attr:`lower`; a
        cyclic error's amplitude: :meth:`phasor`); spreads: profile likelihood.
        """
        if name in fit.factors:
            ref = self.spread_ref[name]
            lo, hi = self.spread_interval(fit, name, level)
            return ref * fit.factors[name], (ref * lo, ref * hi)
        k = self._theta_of(fit, name)
        if len(k) > 1:
            cyc = self.phasor(fit, name, level=level)
            return cyc["amplitude"], cyc["ci"]
        value, (lo, hi) = self.wald(fit, int(k[0]), level)
        least = self.lower[self.blocks[self.sys_index(name)][0]]
        return max(value, least), (max(lo, least), max(hi, least))

    def values(self, fit: Fit) -> dict:
        """Fitted nuisance and systematic values of ``fit``, name -> value (a cyclic error's phasor, complex)."""
        out = {NUISANCE_NAMES[j]: float(v) for j, v in zip(fit.nuis, fit.theta)}
        pos = len(fit.nuis)
        for j in fit.sys:
            k = len(self.blocks[j])
            v = fit.theta[pos:pos + k]
            out[self.systematic[j].name] = complex(v[0], v[1]) if k == 2 else float(v[0])
            pos += k
        return out

    def sys_index(self, name: str) -> int:
        """Index of systematic candidate ``name`` in :attr:`systematic`."""
        return [e.name for e in self.systematic].index(name)

    def structural_aliases(self) -> list[list[str]]:
        """Groups of systematic candidates with (nearly) collinear whitened signatures."""
        Gw = self.whitened_candidates(self.fit((), {}, 0.0))
        norm = Gw / np.linalg.norm(Gw, axis=0)
        corr = np.abs(norm.T @ norm)
        owner = np.repeat(np.arange(len(self.blocks)), [len(c) for c in self.blocks])
        groups, seen = [], set()
        for c in range(corr.shape[0]):
            if c in seen:
                continue
            members = [j for j in np.flatnonzero(corr[c] > 1 - 1e-6) if j not in seen]
            seen.update(members)
            names = list(dict.fromkeys(self.systematic[owner[j]].name for j in members))
            if len(names) > 1:
                groups.append(names)
        return groups
