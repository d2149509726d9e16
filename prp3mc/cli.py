"""Command-line interface: ``prp3mc <command> ...`` (SPEC §6).

A thin wrapper over the Python API. Bad input ends with a one-line message
on stderr and exit status 1 (2 for usage errors), never a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
import numpy as np

from . import __version__
from .errors import Prp3mcError
from .geometry import Geometry
from .sensitivity import FAMILIES, sensitivity

__all__ = ["main"]

COMMANDS: dict[str, tuple[str, type]] = {}


def command(name: str, help: str):
    """Register ``add_arguments`` / ``run`` pairs for a subcommand."""
    def wrap(cls):
        COMMANDS[name] = (help, cls)
        return cls
    return wrap


def add_geometry(p: argparse.ArgumentParser) -> None:
    p.add_argument("--geometry", required=True, metavar="G",
                   help="preset name (u-shape, delta-shape) or geometry TOML file")


def add_pose(p: argparse.ArgumentParser) -> None:
    p.add_argument("--pose", required=True, nargs=3, type=float, metavar=("X", "Y", "PHI"),
                   help="pose: x mm, y mm, phi deg")


def add_json(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print one JSON object to stdout")


def emit_json(obj: dict) -> None:
    json.dump(obj, sys.stdout, indent=2, allow_nan=False)
    sys.stdout.write("\n")


LEGS = ("leg 1", "leg 2", "leg 3")


def _matrix_table(M: np.ndarray, rows=("dx", "dy", "dphi"), cols=LEGS) -> str:
    """Fixed-width table of a 3x3 matrix; round-off below 1e-12 of its scale shows as 0."""
    M = np.where(np.abs(M) < 1e-12 * max(np.abs(M).max(), 1e-300), 0.0, M)
    lines = [" " * 6 + "".join(f"{c:>14}" for c in cols)]
    for r, row in zip(rows, M):
        lines.append(f"{r:<6}" + "".join(f"{v:>14.6g}" for v in row))
    return "\n".join(lines)


@command("sensitivity", "A, B and every sensitivity matrix J_q at one pose")
class Sensitivity:
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
                "prp3mc_version": __version__,
            })
            return
        x, y, phi = args.pose
        out = [f"prp3mc {__version__}  geometry {geometry.name}  pose x={x:g} mm  y={y:g} mm  phi={phi:g} deg",
               "Rows dx, dy in mm and dphi in rad, per mm (a, b, rho, c, e) or per rad (angles) of the parameter.",
               "", "A (forward Jacobian)", _matrix_table(s.A, rows=LEGS, cols=("x", "y", "phi")),
               "", "B (inverse Jacobian)", _matrix_table(s.B, rows=LEGS)]
        for q in FAMILIES:
            out += ["", f"J_{q}", _matrix_table(s.J[q])]
        print("\n".join(out))


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="prp3mc", description="Error analysis of planar 3-PRP parallel manipulators.")
    parser.add_argument("--version", action="version", version=f"prp3mc {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for name, (help_text, cls) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        cls.add_arguments(p)
        p.set_defaults(run=cls.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``prp3mc`` console script; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        args.run(args)
    except Prp3mcError as exc:
        print(f"prp3mc {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"prp3mc {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
