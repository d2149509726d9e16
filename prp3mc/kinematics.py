"""Kinematics of the 3-PRP manipulator, batched over poses of shape (..., 3).

Poses at the boundary are ``[x_mm, y_mm, phi_deg]``; every function here
converts phi to radians once and works in radians inside. Jacobians are
returned in mm and rad (SPEC §1).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .errors import ConvergenceError, InfeasiblePoseError
from .geometry import Geometry

__all__ = [
    "Limits", "Chain", "chain", "as_poses", "inverse_kinematics", "forward_kinematics",
    "jacobians", "jacobian", "check_poses", "feasible", "solve_closure",
]


@dataclass(frozen=True, slots=True)
class Limits:
    """How close to a singularity or a stroke end a pose may come.

    Parameters
    ----------
    min_transmission : float
        Smallest allowed ``|B_ii| = |sin(angle(j_i, l_i))|``; B is singular
        when a passive guide lines up with its slider.
    max_condition : float
        Largest allowed condition number of A after scaling its columns to
        unit norm (unit-free); A is singular at a parallel singularity.
    stroke_tol_mm : float
        Slack on the stroke limits for round-off, mm.
    """

    min_transmission: float = 0.05
    max_condition: float = 1.0e3
    stroke_tol_mm: float = 1e-9


DEFAULT_LIMITS = Limits()


def _unit(t: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(t), np.sin(t)], axis=-1)


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _perp(u: np.ndarray) -> np.ndarray:
    """E u with E the right-angle rotation [[0, -1], [1, 0]]."""
    return np.stack([-u[..., 1], u[..., 0]], axis=-1)


class Chain(NamedTuple):
    """Unit vectors of the three legs at a batch of orientations, each (..., 3, 2)."""

    i: np.ndarray
    j: np.ndarray
    k: np.ndarray
    l: np.ndarray
    m: np.ndarray


def chain(geometry: Geometry, phi_rad: np.ndarray, offsets: dict[str, np.ndarray] | None = None) -> Chain:
    """Unit vectors i, j, k, l, m of eq. (1) for orientations ``phi_rad`` (...,).

    ``offsets`` optionally adds angle perturbations (rad, broadcastable to
    (..., 3)) to alpha, beta, gamma, theta, psi: each turns exactly the
    vectors the parameter appears in, as eq. (5)-(6) require.
    """
    off = offsets or {}
    phi = np.asarray(phi_rad, dtype=float)[..., None]
    ang_i = geometry.rad("alpha") + off.get("alpha", 0.0)
    ang_j = ang_i + geometry.rad("beta") + off.get("beta", 0.0)
    ang_k = ang_j + geometry.rad("gamma") + off.get("gamma", 0.0) + phi
    ang_l = ang_k + geometry.rad("theta") + off.get("theta", 0.0)
    ang_m = phi + geometry.rad("psi") + off.get("psi", 0.0)
    ang_i = np.broadcast_to(ang_i, ang_k.shape)
    ang_j = np.broadcast_to(ang_j, ang_k.shape)
    return Chain(_unit(ang_i), _unit(ang_j), _unit(ang_k), _unit(ang_l), _unit(ang_m))


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


def _ik_rad(geometry: Geometry, xy: np.ndarray, phi: np.ndarray, ch: Chain):
    r = (xy[..., None, :] - geometry.rad("a")[:, None] * ch.i
         - geometry.rad("c")[:, None] * ch.k - geometry.rad("e")[:, None] * ch.m)
    b = _cross(r, ch.l) / _cross(ch.j, ch.l)
    d = _cross(r, ch.j) / _cross(ch.l, ch.j)
    return b, d


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
        check_poses(geometry, poses, limits)
    phi = np.deg2rad(poses[..., 2])
    return _ik_rad(geometry, poses[..., :2], phi, chain(geometry, phi))


def _ab(geometry: Geometry, ch: Chain, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    El = _perp(ch.l)
    lk = np.sum(ch.l * ch.k, axis=-1)
    lm = np.sum(ch.l * ch.m, axis=-1)
    third = -(d + geometry.rad("c") * lk + geometry.rad("e") * lm)
    A = np.concatenate([El, third[..., None]], axis=-1)
    B = np.zeros(A.shape)
    diag = np.sum(El * ch.j, axis=-1)
    B[..., [0, 1, 2], [0, 1, 2]] = diag
    return A, B


def jacobians(geometry: Geometry, poses, *, check: bool = True,
              limits: Limits = DEFAULT_LIMITS) -> tuple[np.ndarray, np.ndarray]:
    """Forward and inverse Jacobians A and B of eq. (3), each (..., 3, 3).

    ``A [dx, dy, dphi]^T = B db`` with x, y, b in mm and phi in rad.
    """
    poses = as_poses(poses)
    if check:
        check_poses(geometry, poses, limits)
    phi = np.deg2rad(poses[..., 2])
    ch = chain(geometry, phi)
    _, d = _ik_rad(geometry, poses[..., :2], phi, ch)
    return _ab(geometry, ch, d)


def jacobian(geometry: Geometry, poses, **kwargs) -> np.ndarray:
    """Kinematic Jacobian J = A^-1 B of eq. (4), shape (..., 3, 3), mm or rad per mm."""
    A, B = jacobians(geometry, poses, **kwargs)
    return np.linalg.solve(A, B)


def _condition(A: np.ndarray) -> np.ndarray:
    scaled = A / np.linalg.norm(A, axis=-2, keepdims=True)
    return np.linalg.cond(scaled)


def _reasons(geometry: Geometry, poses: np.ndarray, limits: Limits):
    """Boolean masks (..., 3) of each refusal reason, and b, d, |B_ii|, cond(A)."""
    phi = np.deg2rad(poses[..., 2])
    ch = chain(geometry, phi)
    b, d = _ik_rad(geometry, poses[..., :2], phi, ch)
    A, B = _ab(geometry, ch, d)
    transmission = np.abs(np.diagonal(B, axis1=-2, axis2=-1))
    cond = _condition(A)
    lo, hi = geometry.stroke_mm[:, 0], geometry.stroke_mm[:, 1]
    tol = limits.stroke_tol_mm
    masks = {
        "below": b < lo - tol,
        "above": b > hi + tol,
        "d": ~(d > 0),
        "transmission": transmission < limits.min_transmission,
        "condition": np.broadcast_to((cond > limits.max_condition)[..., None], b.shape),
    }
    return masks, b, d, transmission, cond


def feasible(geometry: Geometry, poses, limits: Limits = DEFAULT_LIMITS) -> np.ndarray:
    """Mask of shape (...) of poses that :func:`check_poses` would accept."""
    poses = np.asarray(poses, dtype=float)
    finite = np.all(np.isfinite(poses), axis=-1)
    masks, *_ = _reasons(geometry, np.where(finite[..., None], poses, 0.0), limits)
    bad = np.zeros(poses.shape[:-1] + (3,), dtype=bool)
    for mask in masks.values():
        bad |= mask
    return finite & ~np.any(bad, axis=-1)


def check_poses(geometry: Geometry, poses, limits: Limits = DEFAULT_LIMITS) -> None:
    """Raise :class:`InfeasiblePoseError` naming the first refused pose, its leg and limit."""
    poses = as_poses(poses)
    masks, b, d, transmission, cond = _reasons(geometry, poses, limits)
    for reason, mask in masks.items():
        if not np.any(mask):
            continue
        idx = tuple(int(v) for v in np.argwhere(mask)[0])
        pidx, leg = idx[:-1], idx[-1]
        x, y, phi = poses[pidx]
        at = f"pose ({x:g} mm, {y:g} mm, {phi:g} deg) {_where(pidx)}"
        lo, hi = geometry.stroke_mm[leg]
        msg = {
            "below": f"leaves leg {leg + 1}'s stroke: b_{leg + 1} = {b[idx]:.6g} mm < {lo:g} mm",
            "above": f"leaves leg {leg + 1}'s stroke: b_{leg + 1} = {b[idx]:.6g} mm > {hi:g} mm",
            "d": f"has d_{leg + 1} = {d[idx]:.6g} mm <= 0 on leg {leg + 1}",
            "transmission": (f"is near a serial singularity of leg {leg + 1}: |B_{leg + 1}{leg + 1}| = "
                             f"{transmission[idx]:.3g} < {limits.min_transmission:g}"),
            "condition": (f"is near a parallel singularity: cond(A) = {cond[pidx]:.3g} > "
                          f"{limits.max_condition:g}"),
        }[reason]
        raise InfeasiblePoseError(f"{at}{msg}")


def solve_closure(geometry: Geometry, b: np.ndarray, pose0_rad: np.ndarray,
                  offsets: dict[str, np.ndarray] | None = None,
                  contact: np.ndarray | None = None, *, tol: float = 1e-9,
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
    contact : ndarray, shape (..., 3, 2), optional
        Clearance displacement ``rho_i n_i`` of each revolute joint, mm.

    Returns
    -------
    ndarray, shape (..., 3)
        ``[x_mm, y_mm, phi_rad]``.
    """
    off = offsets or {}
    a = geometry.rad("a") + off.get("a", 0.0)
    c = geometry.rad("c") + off.get("c", 0.0)
    e = geometry.rad("e") + off.get("e", 0.0)
    angle_off = {k: v for k, v in off.items() if k in ("alpha", "beta", "gamma", "theta", "psi")}
    shape = np.broadcast_shapes(np.shape(b)[:-1], np.shape(pose0_rad)[:-1])
    pose = np.array(np.broadcast_to(pose0_rad, shape + (3,)), dtype=float)
    b = np.broadcast_to(b, shape + (3,))
    def newton_step():
        ch = chain(geometry, pose[..., 2], angle_off)
        w = (pose[..., None, :2] - a[..., None] * ch.i - b[..., None] * ch.j
             - c[..., None] * ch.k - e[..., None] * ch.m)
        if contact is not None:
            w = w - contact
        El = _perp(ch.l)
        res = np.sum(El * w, axis=-1)
        dphi = (-np.sum(ch.l * w, axis=-1) - c * np.sum(ch.l * ch.k, axis=-1)
                - e * np.sum(ch.l * ch.m, axis=-1))
        jac = np.concatenate([El, dphi[..., None]], axis=-1)
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


def forward_kinematics(geometry: Geometry, b, *, phi_hint_deg: float = 0.0,
                       limits: Limits = DEFAULT_LIMITS) -> np.ndarray:
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
    ch = chain(geometry, grid)                                        # (K, 3, 2)
    El = _perp(ch.l)
    base = (geometry.rad("a")[:, None] * ch.i + geometry.rad("c")[:, None] * ch.k
            + geometry.rad("e")[:, None] * ch.m)                      # (K, 3, 2)
    s = np.sum(El * base, axis=-1) + b[..., None, :] * np.sum(El * ch.j, axis=-1)  # (..., K, 3)
    M = np.broadcast_to(El, s.shape + (2,))
    aug = np.concatenate([M, s[..., None]], axis=-1)                  # (..., K, 3, 3)
    g = np.linalg.det(aug)
    # least-squares T at each grid angle, to check d_i > 0 near each root
    MtM = np.einsum("...kia,...kib->...kab", M, M)
    Mts = np.einsum("...kia,...ki->...ka", M, s)
    Txy = np.linalg.solve(MtM, Mts[..., None])[..., 0]                # (..., K, 2)
    r = Txy[..., None, :] - base - b[..., None, :, None] * ch.j
    with np.errstate(divide="ignore", invalid="ignore"):              # l || j at a singular phi
        d = _cross(r, ch.j) / _cross(ch.l, ch.j)                      # (..., K, 3)
    pos = np.all(d > 0, axis=-1)
    change = (np.sign(g) != np.sign(np.roll(g, -1, axis=-1))) & pos & np.roll(pos, -1, axis=-1)
    change[..., -1] = False
    hint = np.deg2rad(phi_hint_deg)
    dist = np.where(change, np.abs(grid - hint), np.inf)
    kbest = np.argmin(dist, axis=-1)
    found = np.isfinite(np.take_along_axis(dist, kbest[..., None], -1)[..., 0])
    if not np.all(found):
        raise ConvergenceError(f"forward kinematics: no assembly mode with d_i > 0 for "
                               f"{int((~found).sum())} slider position(s)")
    g0 = np.take_along_axis(g, kbest[..., None], -1)[..., 0]
    g1 = np.take_along_axis(g, (kbest + 1)[..., None], -1)[..., 0]
    t = g0 / (g0 - g1)
    phi0 = grid[kbest] + t * (grid[1] - grid[0])
    T0 = np.take_along_axis(Txy, kbest[..., None, None], -2)[..., 0, :]
    pose = solve_closure(geometry, b, np.concatenate([T0, phi0[..., None]], axis=-1))
    out = pose.copy()
    out[..., 2] = np.rad2deg(pose[..., 2])
    return out
