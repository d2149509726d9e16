"""Error-sensitivity matrices H_q and J_q = A^-1 H_q of eq. (7)-(9), batched.

Multiplying the differentiated closure (eq. 5) of leg i by ``l_i^T E^T``
eliminates the passive joint error and gives, per leg, the diagonal entry
``h_q,i`` of H_q:

======== ============================================ ===========
family   h_q,i                                        unit
======== ============================================ ===========
a        (E l_i) . i_i                                mm/mm
alpha    l_i . (a_i i_i + b_i j_i + c_i k_i) + d_i    mm/rad
b        (E l_i) . j_i   (H_b = B)                    mm/mm
beta     l_i . (b_i j_i + c_i k_i) + d_i              mm/rad
rho      1   (worst contact direction n_i = E l_i)    mm/mm
c        (E l_i) . k_i                                mm/mm
gamma    c_i l_i . k_i + d_i                          mm/rad
theta    d_i                                          mm/rad
e        (E l_i) . m_i                                mm/mm
psi      e_i l_i . m_i                                mm/rad
======== ============================================ ===========

Rows of J_q are (dx mm, dy mm, dphi rad); columns are legs 1-3.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from .geometry import Geometry
from .kinematics import DEFAULT_LIMITS, Limits, _ab, _ik_rad, _perp, as_poses, chain, check_poses

__all__ = ["FAMILIES", "LENGTH_FAMILIES", "Sensitivity", "sensitivity", "h_entries", "clearance_angle_rad"]

#: The ten error families of SPEC §1, in the paper's order.
FAMILIES = ("a", "alpha", "b", "beta", "rho", "c", "gamma", "theta", "e", "psi")
#: Families whose parameter is a length (mm); the others are angles (rad).
LENGTH_FAMILIES = frozenset({"a", "b", "rho", "c", "e"})
_OUTPUTS = ("x", "y", "phi")


def h_entries(geometry: Geometry, poses_rad: np.ndarray, families=FAMILIES):
    """Diagonals of H_q and the matrix A at poses ``[x_mm, y_mm, phi_rad]`` (..., 3).

    Returns
    -------
    h : dict of str to ndarray, shape (..., 3)
    A : ndarray, shape (..., 3, 3)
    ch : Chain
        The unit vectors at the poses.
    d : ndarray, shape (..., 3)
        Passive guide lengths, mm.
    """
    ch = chain(geometry, poses_rad[..., 2])
    b, d = _ik_rad(geometry, poses_rad[..., :2], poses_rad[..., 2], ch)
    A, _ = _ab(geometry, ch, d)
    a, c, e = geometry.rad("a"), geometry.rad("c"), geometry.rad("e")
    El = _perp(ch.l)

    def dot(u, v):
        return np.sum(u * v, axis=-1)

    lk, lm = dot(ch.l, ch.k), dot(ch.l, ch.m)
    lj, li = dot(ch.l, ch.j), dot(ch.l, ch.i)
    formulas = {
        "a": lambda: dot(El, ch.i),
        "alpha": lambda: a * li + b * lj + c * lk + d,
        "b": lambda: dot(El, ch.j),
        "beta": lambda: b * lj + c * lk + d,
        "rho": lambda: np.ones_like(d),
        "c": lambda: dot(El, ch.k),
        "gamma": lambda: c * lk + d,
        "theta": lambda: d.copy(),
        "e": lambda: dot(El, ch.m),
        "psi": lambda: e * lm,
    }
    return {q: formulas[q]() for q in families}, A, ch, d


def clearance_angle_rad(ch) -> np.ndarray:
    """Direction omega_i of E l_i (rad), shape (..., 3): the worst contact angle.

    A clearance rho_i at contact angle zeta_i enters H_rho as
    ``rho_i cos(zeta_i - omega_i)``.
    """
    El = _perp(ch.l)
    return np.arctan2(El[..., 1], El[..., 0])


@dataclass(frozen=True, slots=True)
class Sensitivity:
    """A, B and every sensitivity matrix at a batch of poses.

    Attributes
    ----------
    poses : ndarray, shape (..., 3)
        ``[x_mm, y_mm, phi_deg]``.
    A, B : ndarray, shape (..., 3, 3)
        Jacobians of eq. (3).
    H, J : dict of str to ndarray, shape (..., 3, 3)
        H_q and J_q = A^-1 H_q for every family of :data:`FAMILIES`; rows
        (dx mm, dy mm, dphi rad), columns legs 1-3, per mm or rad of parameter.
    """

    poses: np.ndarray
    A: np.ndarray
    B: np.ndarray
    H: dict
    J: dict

    def to_frame(self) -> pd.DataFrame:
        """Tidy table: x_mm, y_mm, phi_deg, output, family, leg, value, unit."""
        flat = self.poses.reshape(-1, 3)
        n = flat.shape[0]
        frames = []
        for q in FAMILIES:
            Jq = self.J[q].reshape(n, 3, 3)
            pose_idx, out_idx, leg_idx = np.meshgrid(np.arange(n), np.arange(3), np.arange(3), indexing="ij")
            per = "mm" if q in LENGTH_FAMILIES else "rad"
            units = np.array([f"mm/{per}", f"mm/{per}", f"rad/{per}"])
            frames.append(pd.DataFrame({
                "x_mm": flat[pose_idx.ravel(), 0], "y_mm": flat[pose_idx.ravel(), 1],
                "phi_deg": flat[pose_idx.ravel(), 2],
                "output": np.array(_OUTPUTS)[out_idx.ravel()], "family": q,
                "leg": leg_idx.ravel() + 1, "value": Jq.ravel(), "unit": units[out_idx.ravel()],
            }))
        return pd.concat(frames, ignore_index=True)


def sensitivity(geometry: Geometry, poses, *, check: bool = True,
                limits: Limits = DEFAULT_LIMITS) -> Sensitivity:
    """A, B, H_q and J_q for every family at poses of shape (..., 3).

    Parameters
    ----------
    geometry : Geometry
    poses : array_like, shape (..., 3)
        ``[x_mm, y_mm, phi_deg]``.
    check : bool
        Refuse poses out of stroke, with d_i <= 0 or near a singularity.

    Returns
    -------
    Sensitivity

    Examples
    --------
    >>> from prp3mc import Geometry, sensitivity
    >>> s = sensitivity(Geometry.from_preset("u-shape"), [10.0, 100.0, 0.0])
    >>> s.J["theta"].shape
    (3, 3)
    """
    poses = as_poses(poses)
    if check:
        check_poses(geometry, poses, limits)
    prad = poses.copy()
    prad[..., 2] = np.deg2rad(prad[..., 2])
    h, A, ch, d = h_entries(geometry, prad)
    Ainv = np.linalg.inv(A)
    H = {q: _diag(v) for q, v in h.items()}
    J = {q: Ainv * v[..., None, :] for q, v in h.items()}
    return Sensitivity(poses=poses, A=A, B=H["b"], H=H, J=J)


def _diag(v: np.ndarray) -> np.ndarray:
    out = np.zeros(v.shape + (3,))
    out[..., [0, 1, 2], [0, 1, 2]] = v
    return out
