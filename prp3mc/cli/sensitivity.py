"""``prp3mc sensitivity``: A, B and every J_q at one pose."""

from .._version import __version__
from ..kinematics.geometry import Geometry
from ..kinematics.sensitivity import FAMILIES, sensitivity
from . import LEGS, provenance, matrix_table, add_geometry, add_json, add_pose, command, emit_json


@command("sensitivity", "A, B and every sensitivity matrix J_q at one pose")
class SensitivityCommand:
    @staticmethod
    def add_arguments(p):
        add_geometry(p)
        add_pose(p)
        add_json(p)

    @staticmethod
    def run(args) -> None:
        geometry = Geometry.load(args.geometry)
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
