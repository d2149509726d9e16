"""Command-line interface: ``prp3mc <command> ...`` (README, *Command line*).

A thin wrapper over the Python API, one module per command in this package;
each registers itself with :func:`command`. Bad input ends with a one-line
message on stderr and exit status 1 (2 for usage errors), never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import json
import sys
import numpy as np

from .._version import __version__
from ..errors import Prp3mcError
from ..provenance import spec_record, versions

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


def add_budget(p: argparse.ArgumentParser) -> None:
    p.add_argument("--budget", required=True, metavar="B", help="preset name (paper) or budget TOML file")


def add_sampling(p: argparse.ArgumentParser, default_samples: int) -> None:
    p.add_argument("--samples", type=positive_int, default=default_samples, metavar="N",
                   help=f"number of samples (default {default_samples})")
    p.add_argument("--seed", type=int, default=None, metavar="S",
                   help="random seed (default: fresh, recorded in the output)")


def add_progress(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--progress", dest="progress", action="store_true", default=None,
                   help="show progress on stderr (default: when stderr is a terminal)")
    g.add_argument("--no-progress", dest="progress", action="store_false")


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def finite_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if value != value or value in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def add_json(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print one JSON object to stdout")


def provenance(args, geometry=None, budget=None, **inputs) -> dict:
    """``{"inputs": ..., "versions": ...}`` of a command's JSON output (what it was run on).

    ``inputs`` names the geometry and budget (preset, or file and sha256),
    the pose if the command takes one, and any further ``inputs`` given
    (seed, sample counts, data files).
    """
    record = {}
    if geometry is not None:
        record["geometry"] = spec_record(args.geometry, geometry)
    if budget is not None:
        record["budget"] = spec_record(args.budget, budget)
    if getattr(args, "pose", None) is not None:
        record["pose"] = dict(zip(("x_mm", "y_mm", "phi_deg"), map(float, args.pose)))
    return {"inputs": record | inputs, "versions": versions()}


def emit_json(obj: dict) -> None:
    json.dump(obj, sys.stdout, indent=2, allow_nan=False)
    sys.stdout.write("\n")


LEGS = ("leg 1", "leg 2", "leg 3")


def matrix_table(M: np.ndarray, rows=("dx", "dy", "dphi"), cols=LEGS) -> str:
    """Fixed-width table of a 3x3 matrix; round-off below 1e-12 of its scale shows as 0."""
    M = np.where(np.abs(M) < 1e-12 * max(np.abs(M).max(), 1e-300), 0.0, M)
    lines = [" " * 6 + "".join(f"{c:>14}" for c in cols)]
    for r, row in zip(rows, M):
        lines.append(f"{r:<6}" + "".join(f"{v:>14.6g}" for v in row))
    return "\n".join(lines)


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2
        self.exit(2, f"{self.prog}: error: {message}\n")


def _load_commands() -> None:
    """Import every command module of this package; each registers itself."""
    for info in pkgutil.iter_modules(__path__):
        importlib.import_module(f"{__name__}.{info.name}")


def build_parser() -> argparse.ArgumentParser:
    _load_commands()
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
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # usage errors (exit 2, one line), --help and --version (exit 0)
        return int(exc.code or 0)
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
