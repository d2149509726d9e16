"""Command-line interface: ``prp3mc <command> ...`` (docs, *The command line*).

A thin wrapper over the Python API, one module per command in this package;
each registers itself with :func:`command`. Bad input ends with a one-line
message on stderr and exit status 1 (2 for usage errors), never a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import importlib
import math
import os
import pkgutil
import signal
import sys
import warnings

import numpy as np

from .._rng import check_seed
from .._version import __version__
from ..errors import Prp3mcError, Prp3mcWarning
from ..limits import Estimate, check
from ..output import claim_output, dumps_json
from ..provenance import spec_record, versions

__all__ = ["main"]

COMMANDS: dict[str, tuple[str, type]] = {}
#: Messages of the prp3mc warnings given during the current command (recorded in its JSON).
WARNINGS: list[str] = []


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
    p.add_argument("--pose", required=True, nargs=3, type=finite_float, metavar=("X", "Y", "PHI"),
                   help="pose: x mm, y mm, phi deg")


def add_budget(p: argparse.ArgumentParser) -> None:
    p.add_argument("--budget", required=True, metavar="B", help="preset name (paper) or budget TOML file")


def add_sampling(p: argparse.ArgumentParser, default_samples: int) -> None:
    p.add_argument("--samples", type=positive_int, default=default_samples, metavar="N",
                   help=f"number of samples (default {default_samples})")
    add_seed(p)


def add_seed(p: argparse.ArgumentParser, help: str = "random seed (default: fresh, recorded in the output)") -> None:
    p.add_argument("--seed", type=seed_arg, default=None, metavar="S", help=help)


def add_output(p: argparse.ArgumentParser, help: str = "output folder (must not exist)") -> None:
    p.add_argument("--out", required=True, metavar="DIR", help=help)
    p.add_argument("--force", action="store_true", help="replace DIR if it exists")


def within_limits(args, estimate: Estimate) -> Estimate:
    """Refuse a request that cannot finish on this machine (see :mod:`prp3mc.limits`)."""
    return check(estimate, max_hours=args.max_hours)


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


def seed_arg(text: str) -> int:
    """A seed: a non-negative integer below 2**63 (:func:`prp3mc._rng.check_seed`)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer seed, got {text!r}") from None
    try:
        return check_seed(value)
    except Prp3mcError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def finite_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def nonnegative_float(text: str) -> float:
    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return value


def positive_float(text: str) -> float:
    value = finite_float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
    return value


def probability(text: str) -> float:
    """A level or probability strictly between 0 and 1."""
    value = finite_float(text)
    if not 0 < value < 1:
        raise argparse.ArgumentTypeError(f"expected a number between 0 and 1 (exclusive), got {text!r}")
    return value


def add_instrument_noise(p: argparse.ArgumentParser, mm: float = 0.0, deg: float = 0.0) -> None:
    """``--instrument-sigma-mm`` and ``--instrument-sigma-deg``: the instrument's noise, with these defaults."""
    p.add_argument("--instrument-sigma-mm", type=nonnegative_float, default=mm, metavar="S",
                   help=f"instrument noise sd of x and y, mm (default {mm:g})")
    p.add_argument("--instrument-sigma-deg", type=nonnegative_float, default=deg, metavar="S",
                   help=f"instrument noise sd of phi, deg (default {deg:g})")


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
        record["budget"] = spec_record(args.budget, budget) | budget.effects_record()
        if budget.missing_inputs:
            record["budget"]["missing_inputs"] = list(budget.missing_inputs)
    if getattr(args, "pose", None) is not None:
        record["pose"] = dict(zip(("x_mm", "y_mm", "phi_deg"), map(float, args.pose)))
    out = {"inputs": record | inputs, "versions": versions()}
    if WARNINGS:
        out["warnings"] = list(WARNINGS)
    return out


def emit_json(obj: dict) -> None:
    """Print ``obj`` as JSON; a NaN or infinity is refused with one line naming where it is."""
    sys.stdout.write(dumps_json(obj) + "\n")


#: How Monte Carlo and Sobol take a budget's [effects] (docs, File formats), said under their tables.
EFFECTS_NOTE = ("Effects: backlash_i and thermal are factors (the approach direction is unknown: delta b_i = "
                "±h_i/2 with probability 1/2 each; one temperature, uniform over temp_range_C); offsets "
                "(offset_q_i) and lead scales (scale_i) are known shifts: no variance share, a systematic part "
                "of the worst case.")

LEGS = ("leg 1", "leg 2", "leg 3")


def matrix_table(M: np.ndarray, rows=("dx", "dy", "dphi"), cols=LEGS) -> str:
    """Fixed-width table of a 3x3 matrix; round-off below 1e-12 of its scale shows as 0."""
    M = np.where(np.abs(M) < 1e-12 * max(np.abs(M).max(), 1e-300), 0.0, M)
    lines = [" " * 6 + "".join(f"{c:>14}" for c in cols)]
    for r, row in zip(rows, M):
        lines.append(f"{r:<6}" + "".join(f"{v:>14.6g}" for v in row))
    return "\n".join(lines)


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2
        self.exit(2, f"{self.prog}: error: {_one_line(message)}\n")


def _command_named(argv: list[str]) -> str | None:
    """The command ``argv`` names (its first word that is no global option), if it is one of ours."""
    words = iter(argv)
    for word in words:
        if word == "--max-hours":
            next(words, None)
        elif not word.startswith("-"):
            return word if word in {info.name for info in pkgutil.iter_modules(__path__)} else None
    return None


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of every command, or of ``command`` alone.

    Each command lives in the module of its name in this package and
    registers itself on import; with ``command`` only that module is
    imported, so a command pays for its own dependencies only.
    """
    for info in pkgutil.iter_modules(__path__):
        if command in (None, info.name):
            importlib.import_module(f"{__name__}.{info.name}")
    parser = _Parser(prog="prp3mc", description="Error analysis of planar 3-PRP parallel manipulators.")
    parser.add_argument("--version", action="version", version=f"prp3mc {__version__}")
    parser.add_argument("--max-hours", type=positive_float, default=None, metavar="H",
                        help="refuse requests estimated to take longer (default 24)")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for name, (help_text, cls) in COMMANDS.items():
        if command in (None, name):
            p = sub.add_parser(name, help=help_text, description=help_text)
            cls.add_arguments(p)
            p.set_defaults(run=cls.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``prp3mc`` console script; returns the exit status.

    Without ``argv`` (the process's own command line, which ends when the
    command does) the garbage collector is told so: once the command's
    modules are imported their objects are frozen out of it, and young
    objects are collected every 10 000 allocations rather than 700 (a
    discrepancy analysis spent 0.15-0.35 s of its 3-4 s in collections that
    walked numba's, scipy's and pandas's objects again and again and freed
    little); every object alive is frozen again before returning, since the
    interpreter's collections at exit would walk all of them, about 0.4 s.
    Objects are still released, files closed and ``atexit`` handlers run as usual.
    """
    if argv is not None:
        return _run(argv)
    status = _run(sys.argv[1:], own_process=True)
    gc.freeze()
    return status


def _input_files(args: argparse.Namespace) -> list[str]:
    """The files a command's arguments name (a study, a campaign, a budget...): ``--force`` never deletes them."""
    values = [v for value in vars(args).values() for v in (value if isinstance(value, list) else [value])]
    return [v for v in values if isinstance(v, (str, os.PathLike)) and str(v) and os.path.isfile(v)]


class _Terminated(KeyboardInterrupt):
    """A SIGTERM, raised where the run is, so that it unwinds (temporary folders, locks) as after Ctrl-C."""


def _terminated(signum, frame):
    raise _Terminated()


def _run(argv: list[str], own_process: bool = False) -> int:
    """Parse ``argv`` and run its command: one line on stderr for any refusal, and the exit status."""
    try:
        args = build_parser(_command_named(argv)).parse_args(argv)
    except SystemExit as exc:  # usage errors (exit 2, one line), --help and --version (exit 0)
        return int(exc.code or 0)
    if own_process:  # see main(); a SIGTERM (timeout, a batch system) ends the run as Ctrl-C does: no leftovers
        signal.signal(signal.SIGTERM, _terminated)
        gc.freeze()
        gc.set_threshold(10_000, *gc.get_threshold()[1:])
    name = f"prp3mc {args.command}"
    WARNINGS.clear()
    show = warnings.showwarning

    def one_line_warning(message, category, filename, lineno, file=None, line=None):
        if not issubclass(category, Prp3mcWarning):
            return show(message, category, filename, lineno, file, line)
        WARNINGS.append(_one_line(message))
        print(f"{name}: warning: {_one_line(message)}", file=sys.stderr)

    try:
        with warnings.catch_warnings(), contextlib.ExitStack() as stack:
            warnings.simplefilter("always", Prp3mcWarning)
            warnings.showwarning = one_line_warning
            if getattr(args, "out", None) is not None:  # claimed before any work (see prp3mc.output)
                stack.enter_context(claim_output(args.out, force=getattr(args, "force", False),
                                                 inputs=_input_files(args)))
            args.run(args)
    except Prp3mcError as exc:
        print(f"{name}: error: {_one_line(exc)}", file=sys.stderr)
        return 1
    except MemoryError:
        print(f"{name}: error: out of memory: use fewer samples or poses", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        print(f"{name}: {'terminated' if isinstance(exc, _Terminated) else 'interrupted'}", file=sys.stderr)
        return 143 if isinstance(exc, _Terminated) else 130
    except BrokenPipeError:
        return 0
    except OSError as exc:  # the file system or the machine, not the request: still one line
        print(f"{name}: error: {_one_line(exc)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
