"""The amplitude of a cyclic screw error: an interval that covers, also near zero.

A cyclic error ``delta b_i = A sin(2 pi b_i / p_i + phi)`` enters the
likelihood through its phasor ``z = A exp(i phi)``, whose real parameters
``c = (Re z, Im z)`` the workflow estimates by generalized least squares:
``c_hat`` with covariance ``V`` (every other value profiled out; the
log-likelihood is quadratic in ``c``). The amplitude is ``|c|`` and the
phase its angle. The profile likelihood-ratio of an amplitude ``A0`` is

    LR(A0) = min over phi of (A0 u(phi) - c_hat)' V^-1 (A0 u(phi) - c_hat),

which is not chi2(1) near ``A0 = 0``: there the phase is not identified and
``LR(0) = c_hat' V^-1 c_hat`` is chi2(2); a Wald interval ``|c_hat| ± 1.96 se``
would miss small amplitudes (``|c_hat|`` is biased up, as a Rice variable).
The interval is therefore a Neyman construction on the LR:
``{A0 >= 0 : LR(A0) <= q(A0)}`` with ``q`` the critical value that gives the
level exactly when ``V = s^2 I`` (then ``|c_hat|`` is Rice(A0, s) and ``LR =
(|c_hat| - A0)^2 / s^2``, so ``q(A0)`` is the quantile of ``(R - t)^2`` for ``R``
Rice(t, 1), ``t = A0 / s``: 5.99 at ``t = 0``, 3.84 for large ``t``, 3.39
at its least near ``t = 2``). For an anisotropic ``V`` (standard errors
``s_min <= s <= s_max`` along its axes) ``q(A0)`` is the largest of
``q(A0 / s)`` over that range; measured coverage of this interval (95 %,
Gaussian ``c_hat``, 6000 draws per case, amplitude 0.5-20 s_min, phases along
and across the axes): 0.941-0.968 for ``s_max / s_min = 1.5``, 0.94-0.97 at 2.
Beyond :data:`ISOTROPY_LIMIT` (coverage fell to 0.93 at a ratio of 4) the
interval is instead the range of ``|c|`` over the joint confidence region
``{c : (c - c_hat)' V^-1 (c - c_hat) <= chi2_2(level)}``, which covers at
least at the level by construction (0.986 for a large amplitude).
"""

from __future__ import annotations

import functools

import numpy as np
from scipy import optimize, special


__all__ = ["amplitude_interval", "profile_lr", "ISOTROPY_LIMIT"]

#: Largest ratio of the phasor's standard errors for which the profile-likelihood interval is used.
ISOTROPY_LIMIT = 2.0
_T_GRID = np.concatenate([np.linspace(0.0, 12.0, 241), [16.0, 32.0, 1e3]])
_PHI = np.linspace(0.0, 2.0 * np.pi, 721)[:-1]
_U = np.stack([np.cos(_PHI), np.sin(_PHI)])                         # (2, K)


@functools.lru_cache(maxsize=4)
def _rice_critical(level: float) -> np.ndarray:
    """``q(t)`` on :data:`_T_GRID`: the ``level`` quantile of ``(R - t)^2`` for R ~ Rice(t, 1)."""
    def covered(s, t):                                  # P(|R - t| <= s), R^2 ~ noncentral chi2(2, t^2)
        upper = special.chndtr((t + s) ** 2, 2.0, t * t)
        return upper - (special.chndtr((t - s) ** 2, 2.0, t * t) if t > s else 0.0)
    return np.array([optimize.brentq(lambda s: covered(s, t) - level, 1e-9, 12.0, xtol=1e-10) ** 2
                     for t in _T_GRID])


def _critical(A: np.ndarray, s_min: float, s_max: float, level: float) -> np.ndarray:
    """``q(A)`` of the module notes: the largest isotropic critical value over standard errors in [s_min, s_max]."""
    q = _rice_critical(level)
    s = np.linspace(s_min, s_max, 33)
    return np.interp(np.asarray(A, dtype=float)[..., None] / s, _T_GRID, q).max(axis=-1)


def profile_lr(A, c_hat: np.ndarray, F: np.ndarray) -> np.ndarray:
    """``LR(A)`` of the module notes for amplitudes ``A`` (n,), with ``F = V^-1`` (2, 2).

    The minimum over the phase from a grid of 720 phases refined by three
    Newton steps on ``f(phi) = A^2 u'Fu - 2 A u'F c_hat``.
    """
    A = np.atleast_1d(np.asarray(A, dtype=float))
    g = F @ c_hat
    quad = np.einsum("ik,ij,jk->k", _U, F, _U)                       # u'Fu per grid phase
    f = A[:, None] ** 2 * quad - 2.0 * A[:, None] * (g @ _U)
    phi = _PHI[np.argmin(f, axis=1)]
    a, b, d = F[0, 0], F[0, 1], F[1, 1]
    for _ in range(3):
        c, s = np.cos(phi), np.sin(phi)
        # u'Fu = a c^2 + 2 b c s + d s^2; its derivatives, and those of u'g
        q1 = 2.0 * (d - a) * c * s + 2.0 * b * (c * c - s * s)
        q2 = 2.0 * (d - a) * (c * c - s * s) - 8.0 * b * c * s
        g1, g2 = -g[0] * s + g[1] * c, -g[0] * c - g[1] * s
        f1, f2 = A ** 2 * q1 - 2.0 * A * g1, A ** 2 * q2 - 2.0 * A * g2
        phi = phi - np.where(f2 > 0, f1 / np.where(f2 > 0, f2, 1.0), 0.0)
    u = np.stack([np.cos(phi), np.sin(phi)], axis=-1)                  # (n, 2)
    r = A[:, None] * u - c_hat
    return np.maximum(np.einsum("ni,ij,nj->n", r, F, r), 0.0)


def amplitude_interval(c_hat, V, level: float = 0.95) -> tuple[float, float]:
    """Confidence interval of the amplitude ``|c|`` of a phasor estimated as ``c_hat`` (2,) with covariance ``V``.

    Parameters
    ----------
    c_hat : array_like, shape (2,)
        Real and imaginary parts of the estimated phasor, mm.
    V : array_like, shape (2, 2)
        Their covariance, mm^2.
    level : float

    Returns
    -------
    (float, float)
        The interval of the module notes, mm (its lower end 0 when the data
        do not exclude a vanishing amplitude).
    """
    c_hat, V = np.asarray(c_hat, dtype=float), np.asarray(V, dtype=float)
    ev = np.linalg.eigvalsh(V)
    if not ev[0] > 0:
        return 0.0, float("inf")
    s_min, s_max = np.sqrt(ev)
    F = np.linalg.inv(V)
    if s_max > ISOTROPY_LIMIT * s_min:
        L = np.linalg.cholesky(V)
        q = -2.0 * np.log1p(-level)                   # the chi2(2) quantile at level
        edge = c_hat[:, None] + np.sqrt(q) * (L @ _U)  # boundary of the joint region
        size = np.hypot(*edge)
        inside = float(c_hat @ F @ c_hat) <= q
        return (0.0 if inside else float(size.min())), float(size.max())
    top = float(np.hypot(*c_hat)) + 8.0 * s_max
    grid = np.linspace(0.0, top, 401)

    def excess(A):
        return profile_lr(A, c_hat, F) - _critical(A, s_min, s_max, level)

    inside = np.flatnonzero(excess(grid) <= 0.0)
    first, last = inside[0], inside[-1]
    lo = 0.0 if first == 0 else optimize.brentq(lambda a: excess(a)[0], grid[first - 1], grid[first], xtol=1e-12)
    hi = optimize.brentq(lambda a: excess(a)[0], grid[last], grid[last + 1], xtol=1e-12)
    return float(lo), float(hi)
