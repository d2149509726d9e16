"""Command-line interface: ``prp3mc <command> ...`` (docs, *The command line*).

A thin wrapper over the Python API, one module per command in this package;
each registers itself with :func:`command`. Bad input ends with a one-line
message on stderr and exit status 1 (2 for usage errors), never a traceback.
A command module imports its analyses (and with them numba, scipy, pandas,
matplotlib) in its ``run``, not at its top: building a parser, as ``prp3mc
COMMAND --help`` does, costs about 0.3 CPU-seconds instead of 2
(``tests/test_lazy_imports.py``).
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import difflib
import importlib
import math
import os
import pkgutil
import re
import signal
import sys
import threading
import warnings
from pathlib import Path

import numpy as np

from .._rng import check_seed
from .._threads import clear_stop, request_stop
from .._version import __version__
from ..errors import OutputExistsError, Prp3mcError, Prp3mcWarning, ResourceError
from ..limits import Estimate, check, format_bytes, format_seconds
from ..output import COMMITTED, claim_output, dumps_json
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


def add_pose_or_region(p: argparse.ArgumentParser) -> None:
    """``--pose X Y PHI``, or ``--region R [--grid N]`` for every pose of a grid, written as a tidy table.

    The table (one row per pose; :func:`emit_table`) goes to stdout as CSV,
    to ``--out FILE.csv``, or into the ``--json`` object as ``rows``.
    """
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--pose", nargs=3, type=finite_float, metavar=("X", "Y", "PHI"),
                       help="one pose: x mm, y mm, phi deg")
    where.add_argument("--region", metavar="R",
                       help="every pose of an N x N grid over a test region: a preset (u-shape, delta-shape) or a "
                            "region TOML file (prp3mc init region); writes a table, one row per pose")
    p.add_argument("--grid", type=positive_int, default=None, metavar="N",
                   help=f"grid size per side with --region (default {DEFAULT_GRID})")
    p.add_argument("--out", dest="out_file", default=None, metavar="FILE.csv",
                   help="with --region: write the table to FILE.csv (default: CSV on stdout)")
    p.add_argument("--force", action="store_true", help="replace FILE.csv if it exists")


#: Grid size per side of ``--region`` when ``--grid`` is not given.
DEFAULT_GRID = 21


def grid_poses(args, estimate=None) -> tuple[np.ndarray, dict]:
    """The poses (N, 3) of ``--region R --grid N`` and their record for ``inputs``.

    ``estimate`` (number of poses -> :class:`~prp3mc.limits.Estimate`), the
    command's memory at that many poses, is checked before the grid is made.

    Raises
    ------
    Prp3mcError
        ``--grid`` or ``--out`` without ``--region``, a region that cannot be read, or a grid that will not fit.
    """
    from ..kinematics.geometry import Region

    if args.region is None:
        if args.grid is not None or args.out_file is not None:
            raise Prp3mcError("--grid and --out go with --region (a table over a grid), not with --pose")
        return np.asarray(args.pose, dtype=float)[None, :], {}
    region = Region.load(args.region)
    n = DEFAULT_GRID if args.grid is None else args.grid
    if estimate is not None:
        within_limits(args, estimate(n * n))
    record = {"region": spec_record(args.region, region) | {"x_mm": list(region.x_mm), "y_mm": list(region.y_mm),
                                                          "phi_deg": region.phi_deg}, "grid": n}
    return region.grid(n).reshape(-1, 3), record


def emit_table(args, frame, doc: dict) -> None:
    """A tidy table (one row per pose, units in the column names): CSV on stdout or ``--out``, or in ``--json``.

    ``doc`` (the command's provenance) goes into the JSON object beside the
    ``rows``; a CSV carries the table alone.
    """
    if args.json:
        emit_json({"columns": list(frame.columns), "rows": frame.to_dict("records"), **doc})
    elif args.out_file is not None:
        from ..output import write_csv

        path = Path(args.out_file)
        if path.exists() and not args.force:
            raise OutputExistsError(f"{path} exists: choose another name or pass --force to replace it")
        path.parent.mkdir(parents=True, exist_ok=True)
        write_csv(frame, path)
        print(f"wrote {path} ({len(frame)} rows)", file=sys.stderr)
    else:
        frame.to_csv(sys.stdout, index=False, lineterminator="\n")


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
    """Refuse a request that will not fit in this machine's memory, or in ``--max-gb`` (:mod:`prp3mc.limits`)."""
    max_gb = getattr(args, "max_gb", None)
    if max_gb is not None and not estimate.bytes <= max_gb * (1 << 30):
        raise ResourceError(f"{estimate.what} needs ~{format_bytes(estimate.bytes)} of memory, more than "
                            f"--max-gb {max_gb:g}: {estimate.hint}")
    return check(estimate)


def add_progress(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--progress", dest="progress", action="store_true", default=None,
                   help="show progress on stderr (default: when stderr is a terminal)")
    g.add_argument("--no-progress", dest="progress", action="store_false")


def positive_int(text: str) -> int:
    return _integer(text, 1, "a positive integer")


def nonnegative_int(text: str) -> int:
    return _integer(text, 0, "an integer >= 0")


def _integer(text: str, least: int, what: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if value < least:
        raise argparse.ArgumentTypeError(f"expected {what}, got {value}")
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
        if budget.correlated:
            record["budget"]["correlation"] = dict(budget.correlation)
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
                "(offset_q_i), lead scales (scale_i) and cyclic screw errors (cyclic_i) are known shifts: no "
                "variance share, a systematic part of the worst case.")

LEGS = ("leg 1", "leg 2", "leg 3")


def matrix_table(M: np.ndarray, rows=("dx", "dy", "dphi"), cols=LEGS) -> str:
    """Fixed-width table of a 3x3 matrix; round-off below 1e-12 of its scale shows as 0."""
    M = np.where(np.abs(M) < 1e-12 * max(np.abs(M).max(), 1e-300), 0.0, M)
    lines = [" " * 6 + "".join(f"{c:>14}" for c in cols)]
    for r, row in zip(rows, M):
        lines.append(f"{r:<6}" + "".join(f"{v:>14.6g}" for v in row))
    return "\n".join(lines)


def _one_line(text: str) -> str:
    """``text`` on one line, printable on any stream (a file name that is not UTF-8 shows as escapes)."""
    return " ".join(str(text).encode("utf-8", "backslashreplace").decode("utf-8").split())


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # a value such as -inf, -1e5 or -nan is a (negative) number, not an option: its option's own type then
        # refuses it in one line ("expected a number > 0"), not argparse's "expected one argument"
        self._negative_number_matcher = re.compile(r"^-(\d+\.?\d*|\.\d+)(e[-+]?\d+)?$|^-(inf|infinity|nan)$",
                                                   re.IGNORECASE)

    def error(self, message):  # one line, exit 2
        self.exit(2, f"{self.prog}: error: {_one_line(message)}\n")


def _command_modules() -> list[str]:
    return [info.name for info in pkgutil.iter_modules(__path__)]


def _command_named(argv: list[str]) -> str | None:
    """The command ``argv`` names (its first word that is no global option), if it is one of ours.

    Raises
    ------
    SystemExit
        (status 2, one line) when that word is no command, with the nearest command names.
    """
    words = iter(argv)
    for word in words:
        if word in ("--max-hours", "--max-gb"):
            next(words, None)
        elif not word.startswith("-"):
            names = _command_modules()
            if word in names:
                return word
            near = difflib.get_close_matches(word, names, n=3, cutoff=0.6)
            hint = f": did you mean {' or '.join(near)}?" if near else f" (commands: {', '.join(sorted(names))})"
            raise SystemExit(_usage_error(f"unknown command {word!r}{hint}"))
    return None


def _usage_error(message: str, prog: str = "prp3mc") -> int:
    """Print a one-line usage error; the exit status 2."""
    print(f"{prog}: error: {_one_line(message)}", file=sys.stderr)
    return 2


def _unknown_options(argv: list[str], parser: argparse.ArgumentParser) -> None:
    """Refuse an option no parser knows, suggesting the nearest ones (``--budgte``: did you mean ``--budget``?).

    argparse would first complain that the misspelt option's intended twin is
    missing; this says what is wrong instead. Abbreviations argparse accepts
    (a unique prefix) pass.

    Raises
    ------
    SystemExit
        (status 2, one line) on an option that is neither known nor a prefix of a known one.
    """
    known = set(parser._option_string_actions)
    prog = "prp3mc"
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                if name in argv:
                    known |= set(sub._option_string_actions)
                    prog = sub.prog
    for word in argv:
        if word == "--":
            break
        option = word.split("=", 1)[0]
        if not option.startswith("--") or option in known or any(k.startswith(option) for k in known):
            continue
        names = sorted(k[2:] for k in known if k.startswith("--"))     # compared without the dashes all share
        near = difflib.get_close_matches(option[2:], names, n=2, cutoff=0.7)
        hint = f": did you mean {' or '.join('--' + n for n in near)}?" if near else f" (see {prog} --help)"
        raise SystemExit(_usage_error(f"unknown option {option}{hint}", prog))


def _command_helps() -> dict[str, str]:
    """``{command: one-line help}`` read from the command modules' ``@command(...)`` lines, importing none.

    ``prp3mc --help`` (and a bare ``prp3mc``) only lists the commands: reading
    their decorators from the source keeps it free of numpy's, scipy's and
    numba's import time (0.05 s instead of seconds).
    """
    helps = {}
    for name in _command_modules():
        tree = ast.parse(Path(__path__[0], f"{name}.py").read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if (isinstance(node, ast.Call) and getattr(node.func, "id", None) == "command"
                    and len(node.args) == 2 and all(isinstance(a, ast.Constant) for a in node.args)):
                helps[node.args[0].value] = node.args[1].value
    return helps


def build_parser(command: str | None = None, *, listing: bool = False) -> argparse.ArgumentParser:
    """The parser of every command, or of ``command`` alone.

    Each command lives in the module of its name in this package and
    registers itself on import; with ``command`` only that module is
    imported, so a command pays for its own dependencies only. With
    ``listing`` no command module is imported: the commands are listed with
    their help (:func:`_command_helps`) but take no arguments (for
    ``prp3mc --help``, ``--version`` and a command line naming no command).
    """
    if listing:
        entries = {name: (help_text, None) for name, help_text in _command_helps().items()}
    else:
        for name in _command_modules():
            if command in (None, name):
                importlib.import_module(f"{__name__}.{name}")
        entries = COMMANDS
    parser = _Parser(prog="prp3mc", description="Error analysis of planar 3-PRP parallel manipulators.")
    parser.add_argument("--version", action="version", version=f"prp3mc {__version__}")
    parser.add_argument("--max-hours", type=positive_float, default=None, metavar="H",
                        help="stop the run after H hours of wall time, writing nothing (default: no limit)")
    parser.add_argument("--max-gb", type=positive_float, default=None, metavar="GB",
                        help="refuse requests estimated to need more memory, GiB (default: what the machine has)")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for name, (help_text, cls) in sorted(entries.items()):
        if command in (None, name):
            p = sub.add_parser(name, help=help_text, description=help_text)
            if cls is not None:
                cls.add_arguments(p)
                p.set_defaults(run=cls.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line ``argv`` (default: the process's own); returns the exit status.

    The ``prp3mc`` console script and ``python -m prp3mc`` come here through
    :func:`prp3mc.__main__.main`. Without ``argv`` (the process's own command
    line) a SIGTERM ends the run as Ctrl-C does.
    """
    if argv is not None:
        return _run(argv)
    try:
        status = _run(sys.argv[1:], own_process=True)
    except KeyboardInterrupt as exc:  # the signal came as the run's end was being decided: it wrote nothing
        status = _stopped(f"prp3mc {_command_named(sys.argv[1:]) or ''}".strip(), _signum(exc))
    _quiet_exit()
    if _SIGNALLED["stopped"]:
        _end_now(status)
    return status


def _end_now(status: int) -> None:
    """End the process of an interrupted run at once, with ``status``.

    The run has unwound (its output folder and locks are gone, its one line
    printed); what the interpreter would still do is wait for worker threads
    to finish the step they are in and collect the whole heap, which took
    2-5 s on a loaded machine after ``prp3mc discrepancy`` and held the
    user's Ctrl-C for nothing. Forked report renderers end with their parent
    (:mod:`prp3mc.reports._render`).
    """
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(status)


def _input_files(args: argparse.Namespace) -> list[str]:
    """The files a command's arguments name (a study, a campaign, a budget...): ``--force`` never deletes them."""
    values = [v for value in vars(args).values() for v in (value if isinstance(value, list) else [value])]
    return [v for v in values if isinstance(v, (str, os.PathLike)) and str(v) and os.path.isfile(v)]


class _Terminated(KeyboardInterrupt):
    """A SIGTERM, raised where the run is, so that it unwinds (temporary folders, locks) as after Ctrl-C."""


def _terminated(signum, frame):
    """SIGTERM and SIGINT of a command's own process: interrupt the run, unless its output is being installed.

    Once the finished folder is moving into place (:data:`prp3mc.output.COMMITTED`)
    the run is complete: the signal is let pass, and the run ends with exit 0
    and its folder whole, never with a folder installed and exit 130/143.
    Once the run's end is decided (an error reported, an interruption being
    reported) a signal is let pass too: it would only cut the one line short.
    """
    if COMMITTED["value"] or _SIGNALLED["decided"]:
        return
    _SIGNALLED["signum"], _SIGNALLED["stopped"] = signum, True
    request_stop()      # the worker threads the run waits for as it unwinds end at their next step
    raise _Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


#: The signal that interrupted the current run, if one did: an error raised on the interrupt's way out
#: (a figure half drawn, a file half written) is reported as the interruption, not as an error of its own;
#: ``stopped``: a signal or the time limit interrupted it (its worker threads were asked to stop);
#: ``timed_out``: the time limit did (a worker's :func:`~prp3mc._threads.check_stop` may raise first).
_SIGNALLED = {"signum": None, "decided": False, "stopped": False, "timed_out": False}


def _signum(exc: KeyboardInterrupt) -> int:
    """The signal an interrupt of the run stands for (SIGTERM for :class:`_Terminated`, else SIGINT)."""
    return signal.SIGTERM if isinstance(exc, _Terminated) else signal.SIGINT


def _stopped(name: str, signum) -> int:
    """The one line and the exit status of a run stopped by ``signum`` (130 for SIGINT, 143 for SIGTERM)."""
    terminated = signum == signal.SIGTERM
    print(f"{name}: {'terminated' if terminated else 'interrupted'}", file=sys.stderr)
    return 143 if terminated else 130


def _quiet_exit() -> None:
    """Ignore SIGINT and SIGTERM from here to the process's end (interpreter finalisation).

    A signal handled while the interpreter tears down (threads, weak sets,
    a figure's draw) ended in tracebacks or a fatal error; the command has
    decided its exit status by now. ``signal.signal`` runs the handler of a
    signal already pending before it replaces it, so none is lost half-way.
    """
    COMMITTED["value"] = True
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, signal.SIG_IGN)


class _TimeUp(KeyboardInterrupt):
    """The ``--max-hours`` limit, raised where the run is, so that it unwinds as after Ctrl-C."""


def _time_up(signum, frame):
    """The ``--max-hours`` alarm: interrupt the run, unless its output is being installed (see :func:`_terminated`)."""
    if COMMITTED["value"] or _SIGNALLED["decided"]:
        return
    _SIGNALLED["stopped"] = _SIGNALLED["timed_out"] = True
    request_stop()
    raise _TimeUp()


def _interrupt_again(hook):
    """``sys.unraisablehook`` that raises a swallowed interrupt of the run again, where the run is.

    A signal handler's exception raised inside a weak reference's callback,
    a ``__del__`` or the garbage collector cannot propagate: Python prints
    "Exception ignored in ..." and carries on, and the run would complete
    as if never interrupted, with that traceback on stderr. The signal is
    sent again instead, from a helper thread a moment later (raised here its
    handler would run inside this hook and be swallowed again), and its handler interrupts
    the run at the run's next step. Any other unraisable exception goes to ``hook``.
    """
    def handle(unraisable):
        exc = unraisable.exc_value
        signum = signal.SIGALRM if isinstance(exc, _TimeUp) else _SIGNALLED["signum"]
        if isinstance(exc, KeyboardInterrupt) and signum is not None and \
                signal.getsignal(signum) in (_terminated, _time_up, signal.SIG_IGN):
            try:
                again = threading.Timer(0.02, os.kill, (os.getpid(), signum))   # once this hook has returned
                again.daemon = True
                again.start()
            except RuntimeError:   # the interpreter is shutting down: the run has ended anyway
                pass
            return
        hook(unraisable)
    return handle


@contextlib.contextmanager
def _stopping_after(seconds: float):
    """Raise :class:`_TimeUp` in this (the main) thread after ``seconds`` of wall time inside the block.

    The alarm's exception, swallowed where it cannot propagate, is raised
    again (:func:`_interrupt_again`) in a caller's process too, not only in
    the command's own (``main(argv)``; there an allocation search went on to
    its memory limit instead).
    """
    previous, hook = signal.signal(signal.SIGALRM, _time_up), sys.unraisablehook
    sys.unraisablehook = _interrupt_again(hook)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        sys.unraisablehook = hook


def _run(argv: list[str], own_process: bool = False) -> int:
    """Parse ``argv`` and run its command: one line on stderr for any refusal, and the exit status."""
    try:
        named = _command_named(argv)
        parser = build_parser(named, listing=named is None)
        _unknown_options(argv, parser)
        args = parser.parse_args(argv)
    except SystemExit as exc:  # usage errors (exit 2, one line), --help and --version (exit 0)
        return int(exc.code or 0)
    if own_process:  # a SIGTERM (timeout, a batch system) ends the run as Ctrl-C does: no leftovers
        signal.signal(signal.SIGTERM, _terminated)
        signal.signal(signal.SIGINT, _terminated)
        sys.unraisablehook = _interrupt_again(sys.__unraisablehook__)
        sys.stdout.reconfigure(errors="surrogateescape")  # a file name that is not UTF-8 prints as its own bytes
    name = f"prp3mc {args.command}"
    WARNINGS.clear()
    COMMITTED["value"] = False
    _SIGNALLED.update(signum=None, decided=False, stopped=False, timed_out=False)
    show = warnings.showwarning

    def one_line_warning(message, category, filename, lineno, file=None, line=None):
        if not issubclass(category, Prp3mcWarning):
            return show(message, category, filename, lineno, file, line)
        if _one_line(message) in WARNINGS:      # once: a budget's warning comes again from every configuration
            return None
        WARNINGS.append(_one_line(message))
        print(f"{name}: warning: {_one_line(message)}", file=sys.stderr)

    try:
        with warnings.catch_warnings(), contextlib.ExitStack() as stack:
            warnings.simplefilter("always", Prp3mcWarning)
            warnings.showwarning = one_line_warning
            if getattr(args, "out", None) is not None:  # claimed before any work (see prp3mc.output)
                stack.enter_context(claim_output(args.out, force=getattr(args, "force", False),
                                                 inputs=_input_files(args)))
            if args.max_hours is not None:  # entered last, left first: the unwinding is not cut short
                stack.enter_context(_stopping_after(3600 * args.max_hours))
            args.run(args)
    except BaseException as exc:
        _SIGNALLED["decided"] = True  # from here a signal is let pass (see _terminated)
        return _ended_by(exc, name, args)
    finally:
        clear_stop()   # the run's pools have emptied: a caller's next analysis (in process) runs whole
    _SIGNALLED["decided"] = True
    return 0


def _ended_by(exc: BaseException, name: str, args: argparse.Namespace) -> int:
    """The one line on stderr and the exit status of a run that ended in ``exc``; re-raised if unforeseen."""
    if isinstance(exc, _TimeUp) or (_SIGNALLED["timed_out"] and isinstance(exc, (KeyboardInterrupt, Exception))):
        print(f"{name}: error: stopped at the --max-hours limit ({format_seconds(3600 * args.max_hours)} of wall "
              "time): nothing was written", file=sys.stderr)
        return 1
    if isinstance(exc, KeyboardInterrupt):
        return _stopped(name, _signum(exc))
    if not isinstance(exc, Exception):  # SystemExit and the like: as Python ends on them
        raise exc
    if _SIGNALLED["signum"] is not None:   # raised by what the signal interrupted
        return _stopped(name, _SIGNALLED["signum"])
    if isinstance(exc, BrokenPipeError):
        return 0
    if isinstance(exc, MemoryError):
        print(f"{name}: error: out of memory: use fewer samples or poses", file=sys.stderr)
        return 1
    if isinstance(exc, (Prp3mcError, OSError)):  # OSError: the file system or the machine, still one line
        print(f"{name}: error: {_one_line(exc)}", file=sys.stderr)
        return 1
    raise exc


if __name__ == "__main__":
    sys.exit(main())
