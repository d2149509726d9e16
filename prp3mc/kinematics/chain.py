"""Kinematics of the 3-PRP manipulator, batched over poses of shape (..., 3).

Poses at the boundary are ``[x_mm, y_mm, phi_deg]``; every function here
converts phi to radians once and works in radians inside. Jacobians are
returned in mm and rad of pose per mm or rad of parameter.

Inside, every leg quantity is an array of shape (3, ...) (legs first, the
batch last, so per-leg constants broadcast along long contiguous rows) and a
unit vector u(t) is carried as its cosine and sine, so dot and cross products
of the chain's unit vectors are plain elementwise arithmetic:
``u.v = cu cv + su sv`` and ``(E u).v = cu sv - su cv``. Public functions
return the usual (..., 3) and (..., 3, 3) shapes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..errors import ConvergenceError, InfeasiblePoseError, ParameterError
from .formulas import a_row, adjugate3, dot, leg_ik, offset_vector, perp_dot, turn
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
    """Cosine and sine of the angles of i, j, k, l, m (eq. 1), each (3, ...), legs first."""

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
        return dot(*self.of(u), *self.of(v))

    def perp_dot(self, u: str, v: str) -> np.ndarray:
        """``(E u) . v`` = sin(angle(v) - angle(u))."""
        return perp_dot(*self.of(u), *self.of(v))

    def of(self, u: str) -> tuple[np.ndarray, np.ndarray]:
        """Cosine and sine of the vector named by letter."""
        return getattr(self, "c" + u), getattr(self, "s" + u)


def legs_first(v, ndim: int) -> np.ndarray:
    """A per-leg value (3,) or (..., 3) as (3, ...) broadcastable against ``ndim`` batch axes."""
    v = np.asarray(v, dtype=float)
    if v.ndim <= 1:       # a scalar, or one value a leg (a geometry's): no axis to move
        return v.reshape(v.shape + (1,) * (ndim * v.ndim))
    v = np.moveaxis(v, -1, 0)
    return v.reshape(v.shape[:1] + (1,) * (ndim + 1 - v.ndim) + v.shape[1:])


def trig(geometry: Geometry, phi_rad, offsets: dict | None = None) -> Trig:
    """:class:`Trig` of the chain at orientations ``phi_rad`` (...), each array (3, ...).

    ``offsets`` optionally adds angle perturbations (rad, broadcastable to
    (..., 3), legs last) to alpha, beta, gamma, theta, psi: each turns exactly
    the vectors it appears in, as eq. (5)-(6) require.
    """
    off = offsets or {}
    phi = np.asarray(phi_rad, dtype=float)
    nd = phi.ndim
    ang = {k: legs_first(geometry.rad(k), nd) + legs_first(off.get(k, 0.0), nd) for k in _ANGLE_KEYS}
    shape = np.broadcast_shapes((3,) + phi.shape, *(a.shape for a in ang.values()))
    cp, sp = np.cos(phi), np.sin(phi)

    def fixed(t):
        return np.broadcast_to(np.cos(t), shape), np.broadcast_to(np.sin(t), shape)

    def turned(t0):  # cos and sin of t0 + phi by the addition formulas: trig only on t0
        c, s = turn(np.cos(t0), np.sin(t0), cp, sp)
        return np.broadcast_to(c, shape), np.broadcast_to(s, shape)

    t_j = ang["alpha"] + ang["beta"]
    t_k = t_j + ang["gamma"]
    return Trig(*fixed(ang["alpha"]), *fixed(t_j), *turned(t_k), *turned(t_k + ang["theta"]),
                *turned(ang["psi"]))


def as_poses(poses: "np.typing.ArrayLike", *, nonempty: bool = False) -> np.ndarray:
    """Validate poses ``[x_mm, y_mm, phi_deg]`` of shape (..., 3); NaN is refused.

    ``nonempty=True`` (the public analyses) also refuses a batch of no poses
    (:class:`~prp3mc.errors.ParameterError`); internal callers may pass empty subsets.
    """
    arr = pose_array(poses)
    if nonempty and arr.size == 0:
        raise ParameterError(f"no poses: the pose batch has shape {arr.shape}; give at least one "
                             "[x_mm, y_mm, phi_deg]")
    if not np.isfinite(arr).all():  # (one flat pass; the pose's index only when there is one)
        raise nonfinite_pose(arr)
    return arr


def pose_array(poses: "np.typing.ArrayLike") -> np.ndarray:
    """Poses as a float array of shape (..., 3), not yet tested for NaN (see :func:`nonfinite_pose`)."""
    arr = np.asarray(poses, dtype=float)
    if arr.ndim == 0 or arr.shape[-1] != 3:
        raise InfeasiblePoseError(f"poses must have shape (..., 3) as [x_mm, y_mm, phi_deg], got {arr.shape}")
    return arr


def nonfinite_pose(arr: np.ndarray) -> InfeasiblePoseError:
    """The error naming the first pose of ``arr`` (..., 3) that holds NaN or infinity."""
    idx = tuple(int(v) for v in np.argwhere(~np.all(np.isfinite(arr), axis=-1))[0])
    return InfeasiblePoseError(f"pose {_where(idx)}contains NaN or infinity: {arr[idx].tolist()}")


def _where(idx: tuple) -> str:
    return f"at index {idx} " if idx else ""


def _offset_vector(geometry: Geometry, tr: Trig, off: dict | None = None):
    """Components of a_i i_i + c_i k_i + e_i m_i, each (3, ...), mm."""
    off = off or {}
    nd = tr.cl.ndim - 1
    a, c, e = (legs_first(geometry.rad(k), nd) + legs_first(off.get(k, 0.0), nd) for k in ("a", "c", "e"))
    return offset_vector(a, c, e, tr.ci, tr.si, tr.ck, tr.sk, tr.cm, tr.sm)


def ik_trig(geometry: Geometry, x: np.ndarray, y: np.ndarray, tr: Trig) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (2): slider positions b and guide lengths d (3, ...) at positions x, y (...) in mm."""
    ox, oy = _offset_vector(geometry, tr)
    return leg_ik(x - ox, y - oy, tr.cj, tr.sj, tr.cl, tr.sl)


class Frame(NamedTuple):
    """Everything the linear model needs at a batch of poses (see :func:`frame`).

    Leg quantities are legs first: ``b``, ``d``, ``transmission`` (3, ...);
    ``A`` and ``Ainv`` are (3, 3, ...) with the batch last.
    """

    tr: Trig
    b: np.ndarray             # mm
    d: np.ndarray             # mm
    A: np.ndarray             # row = leg, column = (x, y, phi)
    Ainv: np.ndarray
    transmission: np.ndarray  # B_ii = (E l_i) . j_i
    condition: np.ndarray     # (...) Frobenius condition of column-scaled A


def _inv3(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse and determinant of 3x3 matrices stored as (3, 3, ...), by cofactors."""
    *adj, det = adjugate3(*A.reshape((9,) + A.shape[2:]))
    inv = np.stack(adj).reshape(A.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv /= det
    return inv, det


def frame(geometry: Geometry, poses: np.ndarray) -> Frame:
    """IK, A, A^-1, B_ii and the conditioning of A at validated poses (..., 3) (phi in degrees)."""
    phi = np.deg2rad(poses[..., 2])
    tr = trig(geometry, phi)
    b, d = ik_trig(geometry, poses[..., 0], poses[..., 1], tr)
    c, e = (legs_first(geometry.rad(k), phi.ndim) for k in ("c", "e"))
    A = np.stack(a_row(c, d, e, tr.ck, tr.sk, tr.cl, tr.sl, tr.cm, tr.sm), axis=1)  # (3 legs, 3 columns, ...)
    Ainv, _ = _inv3(A)
    # condition of A D^-1 (unit columns): ||A D^-1||_F ||D A^-1||_F = sqrt(3) ||D A^-1||_F
    col = np.sqrt(np.sum(A * A, axis=0))                             # (3 columns, ...)
    condition = np.sqrt(3.0 * np.sum((col[:, None] * Ainv) ** 2, axis=(0, 1)))
    condition = np.where(np.isfinite(condition), condition, np.inf)
    return Frame(tr, b, d, A, Ainv, tr.perp_dot("l", "j"), condition)


def batch_last(M: np.ndarray, lead: int = 1) -> np.ndarray:
    """An internal array with ``lead`` leading axes, (3, ...) or (3, 3, ...), in the public
    layout (..., 3) or (..., 3, 3), contiguous."""
    return np.ascontiguousarray(np.moveaxis(M, tuple(range(lead)), tuple(range(-lead, 0))))


def _diag(v: np.ndarray) -> np.ndarray:
    """Diagonal matrices (..., 3, 3) from legs-first values (3, ...)."""
    out = np.zeros(v.shape[1:] + (3, 3))
    for i in range(3):
        out[..., i, i] = v[i]
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
        b, d = fr.b, fr.d
    else:
        b, d = ik_trig(geometry, poses[..., 0], poses[..., 1], trig(geometry, np.deg2rad(poses[..., 2])))
    return batch_last(b), batch_last(d)


def jacobians(geometry: Geometry, poses, *, check: bool = True,
              limits: Limits = DEFAULT_LIMITS) -> tuple[np.ndarray, np.ndarray]:
    """Forward and inverse Jacobians A and B of eq. (3), each (..., 3, 3).

    ``A [dx, dy, dphi]^T = B db`` with x, y, b in mm and phi in rad.
    """
    poses = as_poses(poses)
    fr = validated_frame(geometry, poses, limits) if check else frame(geometry, poses)
    return batch_last(fr.A, 2), _diag(fr.transmission)


def jacobian(geometry: Geometry, poses, *, check: bool = True, limits: Limits = DEFAULT_LIMITS) -> np.ndarray:
    """Kinematic Jacobian J = A^-1 B of eq. (4), shape (..., 3, 3), mm or rad per mm."""
    poses = as_poses(poses)
    fr = validated_frame(geometry, poses, limits) if check else frame(geometry, poses)
    return batch_last(fr.Ainv * fr.transmission, 2)


def _reasons(geometry: Geometry, fr: Frame, limits: Limits) -> dict[str, np.ndarray]:
    """Boolean masks (..., 3) of each refusal reason (legs last, for reporting)."""
    nd = fr.b.ndim - 1
    lo, hi = legs_first(geometry.stroke_mm[:, 0], nd), legs_first(geometry.stroke_mm[:, 1], nd)
    tol = limits.stroke_tol_mm
    masks = {   # singular first: there b, d and A are round-off or infinite, and the other reasons nonsense
        "parallel": ~(np.abs(fr.transmission) > _SINGULAR),
        "singular": np.broadcast_to((~(fr.condition < 1.0 / _SINGULAR) | _guides_parallel(fr.tr))
                                    & (np.abs(fr.b) < _FAR).all(axis=0) & (np.abs(fr.d) < _FAR).all(axis=0),
                                    fr.b.shape),   # a pose far out (1e300 mm) leaves the stroke: said so
        "below": fr.b < lo - tol,
        "above": fr.b > hi + tol,
        "d": ~(fr.d > 0),
        "transmission": ~(np.abs(fr.transmission) >= limits.min_transmission),
        "condition": np.broadcast_to(~(fr.condition <= limits.max_condition), fr.b.shape),
    }
    return {k: np.moveaxis(v, 0, -1) for k, v in masks.items()}


#: |sin| of the angle between a guide and its slider, or 1 / cond(A), below which a pose is singular (not near one).
_SINGULAR = 1e-9
#: Joint values (mm) beyond any machine: a pose that needs them is out of stroke, whatever A's round-off says.
_FAR = 1e12


def _guides_parallel(tr: Trig) -> np.ndarray:
    """Mask (...) of poses where the three guides l_i are parallel (A's position columns have rank 1)."""
    sines = [np.abs(tr.cl[i] * tr.sl[j] - tr.sl[i] * tr.cl[j]) for i, j in ((0, 1), (0, 2), (1, 2))]
    return np.maximum.reduce(sines) < _SINGULAR


def _dependent_legs(A: np.ndarray) -> str:
    """Which legs of a singular A (3, 3) constrain the platform alike, for the refusal."""
    if np.linalg.matrix_rank(A[:, :2], tol=_SINGULAR) < 2:   # unit vectors (-sin l_i, cos l_i) in the rows
        return "the guides of legs 1, 2 and 3 are parallel: the platform can slide along them"
    for i, j in ((0, 1), (0, 2), (1, 2)):
        if np.linalg.norm(np.cross(A[i], A[j])) <= _SINGULAR * np.linalg.norm(A[i]) * np.linalg.norm(A[j]):
            return f"legs {i + 1} and {j + 1} constrain the platform alike (identical or mirrored legs)"
    return "the three legs' constraints are linearly dependent"


def feasible(geometry: Geometry, poses, limits: Limits = DEFAULT_LIMITS) -> np.ndarray:
    """Mask of shape (...) of poses that :func:`check_poses` would accept."""
    poses = np.asarray(poses, dtype=float)
    finite = np.all(np.isfinite(poses), axis=-1)
    with np.errstate(all="ignore"):
        fr = frame(geometry, np.where(finite[..., None], poses, 0.0))
    bad = np.zeros(finite.shape + (3,), dtype=bool)
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
        if np.any(mask):
            idx = tuple(int(v) for v in np.argwhere(mask)[0])
            raise InfeasiblePoseError(refusal(geometry, poses[idx[:-1]], idx[:-1], reason, idx[-1], limits))
    return fr


def refusal(geometry: Geometry, pose: np.ndarray, index: tuple, reason: str, leg: int,
            limits: Limits = DEFAULT_LIMITS) -> str:
    """The one-line message refusing ``pose`` (3,) found at ``index`` of its batch.

    ``reason`` is one of ``parallel, singular, below, above, d, transmission, condition`` (the
    order in which they are tested), ``leg`` the 0-based leg breaking it.
    """
    with np.errstate(all="ignore"):
        fr = frame(geometry, np.asarray(pose, dtype=float))
        why = _dependent_legs(fr.A) if reason == "singular" else ""
    x, y, phi = pose
    at = f"pose ({x:g} mm, {y:g} mm, {phi:g} deg) {_where(index)}"
    lo, hi = geometry.stroke_mm[leg]
    msg = {
        "parallel": (f"is singular: leg {leg + 1}'s guide is parallel to its slider (l_{leg + 1} along "
                     f"j_{leg + 1}), so b_{leg + 1} is undetermined: change theta_{leg + 1}, gamma_{leg + 1} or phi"),
        "singular": f"is singular: A is not invertible ({why}): check the geometry",
        "below": f"leaves leg {leg + 1}'s stroke: b_{leg + 1} = {fr.b[leg]:.6g} mm < {lo:g} mm",
        "above": f"leaves leg {leg + 1}'s stroke: b_{leg + 1} = {fr.b[leg]:.6g} mm > {hi:g} mm",
        "d": f"has d_{leg + 1} = {fr.d[leg]:.6g} mm <= 0 on leg {leg + 1}",
        "transmission": (f"is near a serial singularity of leg {leg + 1}: |B_{leg + 1}{leg + 1}| = "
                         f"{abs(fr.transmission[leg]):.3g} < {limits.min_transmission:g}"),
        "condition": (f"is near a parallel singularity: cond(A) = {fr.condition:.3g} > "
                      f"{limits.max_condition:g}"),
    }[reason]
    return f"{at}{msg}"


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
    shape = np.broadcast_shapes(np.shape(b)[:-1], np.shape(pose0_rad)[:-1],
                                *(np.shape(v)[:-1] for v in off.values() if np.ndim(v)))
    nd = len(shape)
    pose = np.array(np.broadcast_to(pose0_rad, shape + (3,)), dtype=float)
    b = legs_first(b, nd)
    c = legs_first(geometry.rad("c"), nd) + legs_first(off.get("c", 0.0), nd)
    e = legs_first(geometry.rad("e"), nd) + legs_first(off.get("e", 0.0), nd)
    angle_off = {k: v for k, v in off.items() if k in _ANGLE_KEYS}
    cx, cy = (legs_first(contact[0], nd), legs_first(contact[1], nd)) if contact is not None else (0.0, 0.0)

    def newton_step():
        tr = trig(geometry, pose[..., 2], angle_off)
        ox, oy = _offset_vector(geometry, tr, off)
        wx = pose[..., 0] - ox - b * tr.cj - cx
        wy = pose[..., 1] - oy - b * tr.sj - cy
        res = tr.cl * wy - tr.sl * wx
        dphi = -(tr.cl * wx + tr.sl * wy) - c * tr.dot("l", "k") - e * tr.dot("l", "m")
        jac = np.moveaxis(np.stack([-tr.sl, tr.cl, dphi], axis=1), (0, 1), (-2, -1))   # (..., 3, 3)
        try:
            return np.linalg.solve(jac, -np.moveaxis(res, 0, -1)[..., None])[..., 0]
        except np.linalg.LinAlgError:
            raise ConvergenceError("closure equations are singular at a pose (a guide parallel to its slider "
                                   "or dependent legs)") from None

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
    shape = b.shape[:-1]
    bf = b.reshape(-1, 3).T[:, :, None]                              # (3, M, 1)
    tr = Trig(*(v[:, None, :] for v in trig(geometry, grid)))        # each (3, 1, K)
    ox, oy = _offset_vector(geometry, tr)
    # rows (E l_i)^T T = s_i, linear in T = (x, y) for fixed phi
    nx, ny = -tr.sl, tr.cl
    s = (tr.cl * oy - tr.sl * ox) + bf * tr.perp_dot("l", "j")      # (3, M, K)
    nx, ny = np.broadcast_to(nx, s.shape), np.broadcast_to(ny, s.shape)
    g = (nx[0] * (ny[1] * s[2] - s[1] * ny[2]) - ny[0] * (nx[1] * s[2] - s[1] * nx[2])
         + s[0] * (nx[1] * ny[2] - ny[1] * nx[2]))                   # det[E l_i | s_i], (M, K)
    # least-squares T at each grid angle (2x2 normal equations), to check d_i > 0 near each root
    sxx, sxy, syy = (nx * nx).sum(0), (nx * ny).sum(0), (ny * ny).sum(0)
    bx, by = (nx * s).sum(0), (ny * s).sum(0)
    det = sxx * syy - sxy * sxy
    Tx, Ty = (syy * bx - sxy * by) / det, (sxx * by - sxy * bx) / det
    with np.errstate(divide="ignore", invalid="ignore"):              # l || j at a singular phi
        _, d = ik_trig(geometry, Tx, Ty, tr)
    pos = np.all(d > 0, axis=0)
    change = (np.sign(g) != np.sign(np.roll(g, -1, axis=-1))) & pos & np.roll(pos, -1, axis=-1)
    change[..., -1] = False
    dist = np.where(change, np.abs(grid - np.deg2rad(phi_hint_deg)), np.inf)
    k = np.argmin(dist, axis=-1)
    rows = np.arange(len(k))
    if not np.all(np.isfinite(dist[rows, k])):
        raise ConvergenceError(f"forward kinematics: no assembly mode with d_i > 0 for "
                               f"{int((~np.isfinite(dist[rows, k])).sum())} slider position(s)")
    g0, g1 = g[rows, k], g[rows, k + 1]
    phi0 = grid[k] + g0 / (g0 - g1) * (grid[1] - grid[0])
    start = np.stack([Tx[rows, k], Ty[rows, k], phi0], axis=-1)
    pose = solve_closure(geometry, b.reshape(-1, 3), start)
    pose[..., 2] = np.rad2deg(pose[..., 2])
    return pose.reshape(shape + (3,))
