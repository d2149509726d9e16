"""Exact nonlinear response of the perturbed chain, to validate the linear model.

The actuators are commanded by nominal inverse kinematics; the perturbed
chain (eq. 5-6 applied exactly, not to first order) is then closed by Newton's
method and the pose it reaches is compared with the commanded one.
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from ..units import MM2UM
from .geometry import Geometry
from .chain import as_poses, batch_last, frame, solve_closure, validated_frame
from .sensitivity import FAMILIES, LENGTH_FAMILIES, h_entries

__all__ = ["exact_pose_error", "linear_pose_error", "linearization_error_um"]


def _to_internal(errors: dict, shape: tuple) -> tuple[dict, np.ndarray | None]:
    unknown = sorted(set(errors) - set(FAMILIES) - {"zeta"})
    if unknown:
        raise ParameterError(f"unknown error famil{'y' if len(unknown) == 1 else 'ies'} {', '.join(unknown)} "
                          f"(known: {', '.join(FAMILIES)}, zeta)")
    out = {}
    for q, v in errors.items():
        arr = np.asarray(v, dtype=float)
        if not np.all(np.isfinite(arr)):
            raise ParameterError(f"error {q!r} contains NaN or infinity")
        arr = np.broadcast_to(arr, shape + (3,))
        out[q] = arr if q in LENGTH_FAMILIES else np.deg2rad(arr)
    zeta = out.pop("zeta", None)
    return out, zeta


def exact_pose_error(geometry: Geometry, poses, errors: dict, *, check: bool = True) -> np.ndarray:
    """Pose error of the exactly perturbed chain at commanded poses.

    Parameters
    ----------
    geometry : Geometry
    poses : array_like, shape (..., 3)
        Commanded ``[x_mm, y_mm, phi_deg]``.
    errors : dict of str to array_like, each broadcastable to (..., 3)
        Parameter errors per leg: ``a, b, c, e, rho`` in mm; ``alpha, beta,
        gamma, theta, psi`` in degrees; optional ``zeta`` (degrees) is the
        contact angle of each clearance rho_i. Without ``zeta`` each clearance
        acts along the worst direction n_i = E l_i at the commanded pose.

    Returns
    -------
    ndarray, shape (..., 3)
        ``[dx_mm, dy_mm, dphi_deg]``: reached pose minus commanded pose.
    """
    poses = as_poses(poses)
    fr = validated_frame(geometry, poses) if check else frame(geometry, poses)
    deltas, zeta = _to_internal(errors, poses.shape[:-1])
    prad = poses.copy()
    prad[..., 2] = np.deg2rad(poses[..., 2])
    contact = None
    if "rho" in deltas:
        nx, ny = (batch_last(-fr.tr.sl), batch_last(fr.tr.cl)) if zeta is None else (np.cos(zeta), np.sin(zeta))
        contact = (deltas["rho"] * nx, deltas["rho"] * ny)
    offsets = {q: v for q, v in deltas.items() if q not in ("b", "rho")}
    reached = solve_closure(geometry, batch_last(fr.b) + deltas.get("b", 0.0), prad, offsets, contact)
    err = reached - prad
    err[..., 2] = np.rad2deg(err[..., 2])
    return err


def linear_pose_error(geometry: Geometry, poses, errors: dict, *, check: bool = True) -> np.ndarray:
    """Pose error of the linear model, sum over q of J_q dq; same units as :func:`exact_pose_error`."""
    poses = as_poses(poses)
    fr = validated_frame(geometry, poses) if check else frame(geometry, poses)
    deltas, zeta = _to_internal(errors, poses.shape[:-1])
    total = np.zeros(poses.shape)
    Ainv = batch_last(fr.Ainv, 2)
    for q, dq in deltas.items():
        if q == "rho" and zeta is not None:  # cos(zeta - omega), omega the direction of E l
            dq = dq * (np.cos(zeta) * batch_last(-fr.tr.sl) + np.sin(zeta) * batch_last(fr.tr.cl))
        total += np.einsum("...ij,...j->...i", Ainv, batch_last(h_entries(geometry, fr, q)) * dq)
    total[..., 2] = np.rad2deg(total[..., 2])
    return total


def linearization_error_um(geometry: Geometry, poses, errors: dict) -> np.ndarray:
    """Distance between exact and linear position errors, µm, shape (...)."""
    diff = exact_pose_error(geometry, poses, errors) - linear_pose_error(geometry, poses, errors)
    return MM2UM * np.hypot(diff[..., 0], diff[..., 1])
