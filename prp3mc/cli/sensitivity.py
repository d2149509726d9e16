"""``prp3mc sensitivity``: A, B and every J_q at one pose or over a grid."""

from __future__ import annotations

import numpy as np

from .._version import __version__
from ..kinematics.geometry import Geometry
from . import (LEGS, provenance, matrix_table, add_geometry, add_json, add_pose_or_region, command, emit_json, emit_table,
               grid_poses)


@command("sensitivity", "A, B and every sensitivity matrix J_q at one pose or over a region")
class SensitivityCommand:
    @staticmethod
    def add_arguments(p):
        add_geometry(p)
        add_pose_or_region(p)
        add_json(p)

    @staticmethod
    def run(args) -> None:
        from ..kinematics.sensitivity import FAMILIES, sensitivity
        geometry = Geometry.load(args.geometry)
        poses, where = grid_poses(args)
        if args.region is not None:
            emit_table(args, _long_table(sensitivity(geometry, poses), poses), provenance(args, geometry, **where))
            return
        s = sensitivity(geometry, args.pose)
        if args.json:
            emit_json({
                "A": s.A.tolist(), "B": s.B.tolist(),
                "J": {q: s.J[q].tolist() for q in FAMILIES},
                "pose": {"x_mm": args.pose[0], "y_mm": args.pose[1], "phi_deg": args.pose[2]},
                "prp3mc_version": __version__, **provenance(args, geometry),
            })
            return
        x, y, phi = args.pose
        out = [f"prp3mc {__version__}  geometry {geometry.name}  pose x={x:g} mm  y={y:g} mm  phi={phi:g} deg",
               "Rows dx, dy in mm and dphi in rad, per mm (a, b, rho, c, e) or per rad (angles) of the parameter.",
               "", "A (forward Jacobian)", matrix_table(s.A, rows=LEGS, cols=("x", "y", "phi")),
               "", "B (inverse Jacobian)", matrix_table(s.B, rows=LEGS)]
        for q in FAMILIES:
            out += ["", f"J_{q}", matrix_table(s.J[q])]
        print("\n".join(out))


def _long_table(s, poses: np.ndarray) -> pd.DataFrame:
    """One row per pose, matrix, row and column (``matrix`` A, B or J_q; units as in the text output)."""
    from ..kinematics.sensitivity import FAMILIES, sensitivity
    import pandas as pd
    mats = {"A": (s.A, LEGS, ("x", "y", "phi")), "B": (s.B, LEGS, LEGS)}
    mats.update({f"J_{q}": (s.J[q], ("dx", "dy", "dphi"), LEGS) for q in FAMILIES})
    parts = []
    for name, (M, rows, cols) in mats.items():
        n = poses.shape[0]
        parts.append(pd.DataFrame({
            "x_mm": np.repeat(poses[:, 0], 9), "y_mm": np.repeat(poses[:, 1], 9),
            "phi_deg": np.repeat(poses[:, 2], 9), "matrix": name,
            "row": np.tile(np.repeat(rows, 3), n), "column": np.tile(np.tile(cols, 3), n),
            "value": np.asarray(M).reshape(n, 9).ravel()}))
    return pd.concat(parts, ignore_index=True)
