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

from .._result import freeze, short_repr
from ..units import POSE_OUTPUTS
from .formulas import FAMILIES, LENGTH_FAMILIES, h_entry
from .geometry import Geometry
from .chain import (
    DEFAULT_LIMITS, Frame, Limits, _diag, as_poses, batch_last, frame, legs_first, validated_frame,
)

__all__ = ["FAMILIES", "LENGTH_FAMILIES", "Sensitivity", "sensitivity", "h_entries"]


def h_entries(geometry: Geometry, fr: Frame, family: str) -> np.ndarray:
    """Diagonal of H_q for ``family`` at the poses of a :class:`Frame`, legs first: (3, ...)."""
    if family not in FAMILIES:
        raise KeyError(f"unknown error family {family!r}")
    tr, d = fr.tr, fr.d
    a, c, e = (legs_first(geometry.rad(k), d.ndim - 1) for k in ("a", "c", "e"))
    h = h_entry(FAMILIES.index(family), a, fr.b, c, d, e, *tr)
    return h if np.ndim(h) else np.ones_like(d)


@dataclass(frozen=True, slots=True, repr=False)
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

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        return short_repr(self, "poses") + f" with J of {', '.join(self.J)}"

    def to_frame(self) -> pd.DataFrame:
        """Tidy table: x_mm, y_mm, phi_deg, output, family, leg, value, unit."""
        flat = self.poses.reshape(-1, 3)
        n = flat.shape[0]
        pose_idx, out_idx, leg_idx = (g.ravel() for g in np.meshgrid(np.arange(n), np.arange(3), np.arange(3),
                                                                      indexing="ij"))
        frames = []
        for q in FAMILIES:
            per = "mm" if q in LENGTH_FAMILIES else "rad"
            units = np.array([f"mm/{per}", f"mm/{per}", f"rad/{per}"])
            frames.append(pd.DataFrame({
                "x_mm": flat[pose_idx, 0], "y_mm": flat[pose_idx, 1], "phi_deg": flat[pose_idx, 2],
                "output": np.array(POSE_OUTPUTS)[out_idx], "family": q, "leg": leg_idx + 1,
                "value": self.J[q].reshape(n, 3, 3).ravel(), "unit": units[out_idx],
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
    fr = validated_frame(geometry, poses, limits) if check else frame(geometry, poses)
    h = {q: h_entries(geometry, fr, q) for q in FAMILIES}
    H = {q: _diag(v) for q, v in h.items()}
    J = {q: batch_last(fr.Ainv * v, 2) for q, v in h.items()}
    return Sensitivity(poses=poses, A=batch_last(fr.A, 2), B=H["b"], H=H, J=J)
