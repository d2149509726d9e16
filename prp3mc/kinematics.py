"""Kinematics of the 3-PRP manipulator, batched over poses of shape (..., 3).

Poses at the boundary are ``[x_mm, y_mm, phi_deg]``; every function here
converts phi to radians once and works in radians inside. Jacobians are
returned in mm and rad (SPEC §1).

Inside, every leg quantity is an array of shape (..., 3) (legs last) and a
unit vector u(t) is carried as its cosine and sine, so dot and cross products
of the chain's unit vectors are plain elementwise arithmetic on contiguous
arrays: ``u.v = cu cv + su sv`` and ``(E u).v = cu sv - su cv``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .errors import ConvergenceError, InfeasiblePoseError
from .geometry import Geometry

__all__ = [
    "Limits", "as_poses", "inverse_kinematics", "forward_kinematics", "jacobians", "jacobian",
    "check_poses", "feasible", "solve_closure",
]

_ANGLE_KEYS = ("alpha", "beta", "gamma", "theta", "psi")


@dataclass(frozen=True, slots=True)
class Limits:
    """How close to a singularity or a stroke end a pose may come.

    Parameters
    ----------
    min_transmission : float
        Smallest allowed ``|B_ii| = |sin(angle(j_i, l_i))|``; B is singular
        when a passive guide lines up with its slider.
    max_condition : float
        Largest allowed Frobenius condition number of A after scaling its
        columns to unit norm (unit-free); A is singular at a parallel
        singularity. The reference geometries stay below 5 in their regions.
    stroke_tol_mm : float
        Slack on the stroke limits for round-off, mm.
    """

    min_transmission: float = 0.05
    max_condition: float = 1.0e3
    stroke_tol_mm: float = 1e-9


DEFAULT_LIMITS = Limits()


class Trig(NamedTuple):
    """Cosine and sine of the angles of i, j, k, l, m (eq. 1), each (..., 3)."""

    ci: np.ndarray
    si: np.ndarray
    cj: np.ndarray
    sj: np.ndarray
    ck: np.ndarray
    sk: np.ndarray
    cl: np.ndarray
    sl: np.ndarray
    cm: np.ndarray
    sm: np.ndarray

    def dot(self, u: str, v: str) -> np.ndarray:
        """``u . v`` for two of the vectors named by letter, e.g. ``dot("l", "k")``."""
        return getattr(self, "c" + u) * getattr(self, "c" + v) + getattr(self, "s" + u) * getattr(self, "s" + v)

    def perp_dot(self, u: str, v: str) -> np.ndarray:
        """``(E u) . v`` = sin(angle(v) - angle(u))."""
        return getattr(self, "c" + u) * getattr(self, "s" + v) - getattr(self, "s" + u) * getattr(self, "c" + v)


def trig(geometry: Geometry, phi_rad, offsets: dict | None = None) -> Trig:
    """:class:`Trig` of the chain at orientations ``phi_rad`` (...,).

    ``offsets`` optionally adds angle perturbations (rad, broadcastable to
    (..., 3)) to alpha, beta, gamma, theta, psi: each turns exactly the
    vectors it appears in, as eq. (5)-(6) require.
    """
    off = offsets or {}
    phi = np.asarray(phi_rad, dtype=float)[..., None]
    shape = np.broadcast_shapes(phi.shape[:-1] + (3,), *(np.shape(v) for v in off.values()))
    ang = {k: geometry.rad(k) + off.get(k, 0.0) for k in _ANGLE_KEYS}
    t_i = ang["alpha"]
    t_j = t_i + ang["beta"]
    cp, sp = np.cos(phi), np.sin(phi)

    def turned(t0):  # cos and sin of t0 + phi by the addition formulas: trig only on t0
        c0, s0 = np.cos(t0), np.sin(t0)
        return np.broadcast_to(c0 * cp - s0 * sp, shape), np.broadcast_to(s0 * cp + c0 * sp, shape)

    t_k = t_j + ang["gamma"]
    ck, sk = turned(t_k)
    cl, sl = turned(t_k + ang["theta"])
    cm, sm = turned(ang["psi"])
    return Trig(np.broadcast_to(np.cos(t_i), shape), np.broadcast_to(np.sin(t_i), shape),
                np.broadcast_to(np.cos(t_j), shape), np.broadcast_to(np.sin(t_j), shape),
                ck, sk, cl, sl, cm, sm)


def as_poses(poses: "np.typing.ArrayLike") -> np.ndarray:
    """Validate poses ``[x_mm, y_mm, phi_deg]`` of shape (..., 3); NaN is refused."""
    arr = np.asarray(poses, dtype=float)
    if arr.ndim == 0 or arr.shape[-1] != 3:
        raise InfeasiblePoseError(f"poses must have shape (..., 3) as [x_mm, y_mm, phi_deg], got {arr.shape}")
    bad = ~np.all(np.isfinite(arr), axis=-1)
    if np.any(bad):
        idx = tuple(int(v) for v in np.argwhere(bad)[0])
        raise InfeasiblePoseError(f"pose {_where(idx)}contains NaN or infinity: {arr[idx].tolist()}")
    return arr


def _where(idx: tuple) -> str:
    return f"at index {idx} " if idx else ""


def _offset_vector(geometry: Geometry, tr: Trig, off: dict | None = None):
    """Components of a_i i_i + c_i k_i + e_i m_i, each (..., 3), mm."""
    off = off or {}
    a = geometry.rad("a") + off.get("a", 0.0)
    c = geometry.rad("c") + off.get("c", 0.0)
    e = geometry.rad("e") + off.get("e", 0.0)
    return a * tr.ci + c * tr.ck + e * tr.cm, a * tr.si + c * tr.sk + e * tr.sm


def ik_trig(geometry: Geometry, x: np.ndarray, y: np.ndarray, tr: Trig) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (2): slider positions b and guide lengths d (..., 3) at positions x, y (...,) in mm."""
    ox, oy = _offset_vector(geometry, tr)
    rx, ry = x[..., None] - ox, y[..., None] - oy
    b = (rx * tr.sl - ry * tr.cl) / (tr.cj * tr.sl - tr.sj * tr.cl)
    d = (rx * tr.sj - ry * tr.cj) / (tr.cl * tr.sj - tr.sl * tr.cj)
    return b, d


class Frame(NamedTuple):
    """Everything the linear model needs at a batch of poses (see :func:`frame`)."""

    tr: Trig
    b: np.ndarray          # (..., 3) mm
    d: np.ndarray          # (..., 3) mm
    A: np.ndarray          # (..., 3, 3)
    Ainv: np.ndarray       # (..., 3, 3)
    transmission: np.ndarray  # (..., 3) B_ii = (E l_i) . j_i
    condition: np.ndarray  # (...)  Frobenius condition of column-scaled A


def _inv3(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse and determinant of 3x3 matrices (..., 3, 3) by cofactors."""
    a, b, c = A[..., 0, 0], A[..., 0, 1], A[..., 0, 2]
    d, e, f = A[..., 1, 0], A[..., 1, 1], A[..., 1, 2]
    g, h, i = A[..., 2, 0], A[..., 2, 1], A[..., 2, 2]
    c00, c01, c02 = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * c00 + b * c01 + c * c02
    adj = np.stack([c00, c * h - b * i, b * f - c * e,
                    c01, a * i - c * g, c * d - a * f,
                    c02, b * g - a * h, a * e - b * d], axis=-1).reshape(A.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        return adj / det[..., None, None], det


def frame(geometry: Geometry, poses: np.ndarray) -> Frame:
    """IK, A, A^-1, B_ii and the conditioning of A at validated poses (..., 3) (phi in degrees)."""
    phi = np.deg2rad(poses[..., 2])
    tr = trig(geometry, phi)
    b, d = ik_trig(geometry, poses[..., 0], poses[..., 1], tr)
    w = -(d + geometry.rad("c") * tr.dot("l", "k") + geometry.rad("e") * tr.dot("l", "m"))
    A = np.stack([-tr.sl, tr.cl, w], axis=-1)
    Ainv, _ = _inv3(A)
    # condition of A D^-1 (unit columns): ||A D^-1||_F ||D A^-1||_F = sqrt(3) ||D A^-1||_F
    col = np.sqrt(np.sum(A * A, axis=-2))
    condition = np.sqrt(3.0 * np.sum((col[..., :, None] * Ainv) ** 2, axis=(-2, -1)))
    condition = np.where(np.isfinite(condition), condition, np.inf)
    return Frame(tr, b, d, A, Ainv, tr.perp_dot("l", "j"), condition)


def _diag(v: np.ndarray) -> np.ndarray:
    out = np.zeros(v.shape + (3,))
    out[..., [0, 1, 2], [0, 1, 2]] = v
    return out


def inverse_kinematics(geometry: Geometry, poses, *, check: bool = True,
                       limits: Limits = DEFAULT_LIMITS) -> tuple[np.ndarray, np.ndarray]:
    """Actuated and passive joint values of eq. (2).

    Parameters
    ----------
    geometry : Geometry
    poses : array_like, shape (..., 3)
        ``[x_mm, y_mm, phi_deg]``.
    check : bool
        Refuse poses out of stroke, with ``d_i <= 0`` or near a singularity.

    Returns
    -------
    b, d : ndarray, shape (..., 3)
        Slider positions and passive guide lengths of legs 1-3, mm.
    """
    poses = as_poses(poses)
    if check:
        fr = validated_frame(geometry, poses, limits)
        return fr.b, fr.d
    return ik_trig(geometry, poses[..., 0], poses[..., 1], trig(geometry, np.deg2rad(poses[..., 2])))


def jacobians(geometry: Geometry, poses, *, check: bool = True,
              limits: Limits = DEFAULT_LIMITS) -> tuple[np.ndarray, np.ndarray]:
    """Forward and inverse Jacobians A and B of eq. (3), each (..., 3, 3).

    ``A [dx, dy, dphi]^T = B db`` with x, y, b in mm and phi in rad.
    """
    poses = as_poses(poses)
    fr = validated_frame(geometry, poses, limits) if check else frame(geometry, poses)
    return fr.A, _diag(fr.transmission)


def jacobian(geometry: Geometry, poses, *, check: bool = True, limits: Limits = DEFAULT_LIMITS) -> np.ndarray:
    """Kinematic Jacobian J = A^-1 B of eq. (4), shape (..., 3, 3), mm or rad per mm."""
    poses = as_poses(poses)
    fr = validated_frame(geometry, poses, limits) if check else frame(geometry, poses)
    return fr.Ainv * fr.transmission[..., None, :]


def _reasons(geometry: Geometry, fr: Frame, limits: Limits) -> dict[str, np.ndarray]:
    """Boolean masks (..., 3) of each refusal reason."""
    lo, hi = geometry.stroke_mm[:, 0], geometry.stroke_mm[:, 1]
    tol = limits.stroke_tol_mm
    return {
        "below": fr.b < lo - tol,
        "above": fr.b > hi + tol,
        "d": ~(fr.d > 0),
        "transmission": ~(np.abs(fr.transmission) >= limits.min_transmission),
        "condition": np.broadcast_to(~(fr.condition <= limits.max_condition)[..., None], fr.b.shape),
    }


def feasible(geometry: Geometry, poses, limits: Limits = DEFAULT_LIMITS) -> np.ndarray:
    """Mask of shape (...) of poses that :func:`check_poses` would accept."""
    poses = np.asarray(poses, dtype=float)
    finite = np.all(np.isfinite(poses), axis=-1)
    with np.errstate(all="ignore"):
        fr = frame(geometry, np.where(finite[..., None], poses, 0.0))
    bad = np.zeros(fr.b.shape, dtype=bool)
    for mask in _reasons(geometry, fr, limits).values():
        bad |= mask
    return finite & ~np.any(bad, axis=-1)


def validated_frame(geometry: Geometry, poses: np.ndarray, limits: Limits = DEFAULT_LIMITS) -> Frame:
    """:func:`frame` at poses, raising :class:`InfeasiblePoseError` for the first refused one.

    The message names the pose, the leg and the limit it breaks.
    """
    with np.errstate(all="ignore"):
        fr = frame(geometry, poses)
    for reason, mask in _reasons(geometry, fr, limits).items():
        if not np.any(mask):
            continue
        idx = tuple(int(v) for v in np.argwhere(mask)[0])
        pidx, leg = idx[:-1], idx[-1]
        x, y, phi = poses[pidx]
        at = f"pose ({x:g} mm, {y:g} mm, {phi:g} deg) {_where(pidx)}"
        lo, hi = geometry.stroke_mm[leg]
        msg = {
            "below": f"leaves leg {leg + 1}'s stroke: b_{leg + 1} = {fr.b[idx]:.6g} mm < {lo:g} mm",
            "above": f"leaves leg {leg + 1}'s stroke: b_{leg + 1} = {fr.b[idx]:.6g} mm > {hi:g} mm",
            "d": f"has d_{leg + 1} = {fr.d[idx]:.6g} mm <= 0 on leg {leg + 1}",
            "transmission": (f"is near a serial singularity of leg {leg + 1}: |B_{leg + 1}{leg + 1}| = "
                             f"{abs(fr.transmission[idx]):.3g} < {limits.min_transmission:g}"),
            "condition": (f"is near a parallel singularity: cond(A) = {fr.condition[pidx]:.3g} > "
                          f"{limits.max_condition:g}"),
        }[reason]
        raise InfeasiblePoseError(f"{at}{msg}")
    return fr


def check_poses(geometry: Geometry, poses, limits: Limits = DEFAULT_LIMITS) -> None:
    """Raise :class:`InfeasiblePoseError` naming the first refused pose, its leg and limit."""
    validated_frame(geometry, as_poses(poses), limits)


def solve_closure(geometry: Geometry, b: np.ndarray, pose0_rad: np.ndarray,
                  offsets: dict[str, np.ndarray] | None = None,
                  contact: tuple[np.ndarray, np.ndarray] | None = None, *, tol: float = 1e-9,
                  max_iter: int = 50) -> np.ndarray:
    """Newton solve of the closure equations for the pose, batched.

    Solves ``(E l_i) . (T - a_i i_i - b_i j_i - c_i k_i - e_i m_i - rho_i n_i) = 0``
    for i = 1, 2, 3 (eq. 1 with d_i eliminated).

    Parameters
    ----------
    geometry : Geometry
    b : ndarray, shape (..., 3)
        Slider positions, mm.
    pose0_rad : ndarray, shape (..., 3)
        Start ``[x_mm, y_mm, phi_rad]``.
    offsets : dict, optional
        Parameter perturbations broadcastable to (..., 3): ``a, c, e`` in mm,
        ``alpha, beta, gamma, theta, psi`` in rad.
    contact : (ndarray, ndarray), optional
        x and y components (..., 3) of the clearance displacement rho_i n_i, mm.

    Returns
    -------
    ndarray, shape (..., 3)
        ``[x_mm, y_mm, phi_rad]``.
    """
    off = offsets or {}
    c = geometry.rad("c") + off.get("c", 0.0)
    e = geometry.rad("e") + off.get("e", 0.0)
    angle_off = {k: v for k, v in off.items() if k in _ANGLE_KEYS}
    shape = np.broadcast_shapes(np.shape(b)[:-1], np.shape(pose0_rad)[:-1])
    pose = np.array(np.broadcast_to(pose0_rad, shape + (3,)), dtype=float)
    b = np.broadcast_to(b, shape + (3,))

    def newton_step():
        tr = trig(geometry, pose[..., 2], angle_off)
        ox, oy = _offset_vector(geometry, tr, off)
        wx = pose[..., 0, None] - ox - b * tr.cj
        wy = pose[..., 1, None] - oy - b * tr.sj
        if contact is not None:
            wx, wy = wx - contact[0], wy - contact[1]
        res = tr.cl * wy - tr.sl * wx
        dphi = -(tr.cl * wx + tr.sl * wy) - c * tr.dot("l", "k") - e * tr.dot("l", "m")
        jac = np.stack([-tr.sl, tr.cl, dphi], axis=-1)
        return np.linalg.solve(jac, -res[..., None])[..., 0]

    for _ in range(max_iter):
        step = newton_step()
        pose += step
        if np.all(np.abs(step) < tol * (1.0 + np.abs(pose))):
            pose += newton_step()  # quadratic convergence: one more step reaches round-off
            return pose
    raise ConvergenceError(f"closure equations did not converge in {max_iter} Newton steps for "
                           f"{int(np.sum(np.any(np.abs(step) >= tol * (1.0 + np.abs(pose)), axis=-1)))} "
                           f"pose(s)")


def forward_kinematics(geometry: Geometry, b, *, phi_hint_deg: float = 0.0) -> np.ndarray:
    """Exact forward kinematics: the pose reached by slider positions ``b``.

    For fixed phi the closure equations are linear in T, so the assembly
    modes are the roots of ``g(phi) = det[E l_i | s_i]``; phi is scanned on a
    0.5 degree grid, the sign change with all d_i > 0 nearest ``phi_hint_deg``
    is taken and polished by Newton on the full system.

    Parameters
    ----------
    b : array_like, shape (..., 3)
        Slider positions of legs 1-3, mm.
    phi_hint_deg : float
        Orientation the wanted assembly mode is nearest to, degrees.

    Returns
    -------
    ndarray, shape (..., 3)
        ``[x_mm, y_mm, phi_deg]``.

    Raises
    ------
    ConvergenceError
        No assembly mode with positive d_i, or Newton did not converge.
    """
    b = np.asarray(b, dtype=float)
    if b.ndim == 0 or b.shape[-1] != 3 or not np.all(np.isfinite(b)):
        raise InfeasiblePoseError("slider positions b must be finite with shape (..., 3)")
    grid = np.deg2rad(np.arange(-180.0, 180.0, 0.5))
    tr = trig(geometry, grid)                                         # each (K, 3)
    ox, oy = _offset_vector(geometry, tr)
    # rows (E l_i)^T T = s_i: linear in T = (x, y) for fixed phi
    s = (tr.cl * oy - tr.sl * ox) + b[..., None, :] * tr.perp_dot("l", "j")   # (..., K, 3)
    M = np.broadcast_to(np.stack([-tr.sl, tr.cl], axis=-1), s.shape + (2,))
    g = np.linalg.det(np.concatenate([M, s[..., None]], axis=-1))
    # least-squares T at each grid angle, to check d_i > 0 near each root
    MtM = np.einsum("...kia,...kib->...kab", M, M)
    Txy = np.linalg.solve(MtM, np.einsum("...kia,...ki->...ka", M, s)[..., None])[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):              # l || j at a singular phi
        _, d = ik_trig(geometry, Txy[..., 0], Txy[..., 1], tr)
    pos = np.all(d > 0, axis=-1)
    change = (np.sign(g) != np.sign(np.roll(g, -1, axis=-1))) & pos & np.roll(pos, -1, axis=-1)
    change[..., -1] = False
    dist = np.where(change, np.abs(grid - np.deg2rad(phi_hint_deg)), np.inf)
    kbest = np.argmin(dist, axis=-1)
    found = np.isfinite(np.take_along_axis(dist, kbest[..., None], -1)[..., 0])
    if not np.all(found):
        raise ConvergenceError(f"forward kinematics: no assembly mode with d_i > 0 for "
                               f"{int((~found).sum())} slider position(s)")
    g0 = np.take_along_axis(g, kbest[..., None], -1)[..., 0]
    g1 = np.take_along_axis(g, (kbest + 1)[..., None], -1)[..., 0]
    phi0 = grid[kbest] + g0 / (g0 - g1) * (grid[1] - grid[0])
    T0 = np.take_along_axis(Txy, kbest[..., None, None], -2)[..., 0, :]
    pose = solve_closure(geometry, b, np.concatenate([T0, phi0[..., None]], axis=-1))
    pose[..., 2] = np.rad2deg(pose[..., 2])
    return pose
