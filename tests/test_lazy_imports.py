"""What the command line imports before a command runs: heavy libraries are imported where they are used."""

import subprocess
import sys

import pytest


@pytest.mark.parametrize("command", ["discrepancy", None])
def test_command_line_parser_does_without_scipy_stats_salib_matplotlib(command):
    """Building the parser of ``prp3mc discrepancy`` (or of every command, as ``prp3mc --help`` does) imports
    none of scipy.stats, SALib and matplotlib (together over a second): the analyses import them when they run."""
    code = (f"import sys; from prp3mc.cli import build_parser; build_parser({command!r}); "
            "print(sorted(m for m in ('scipy.stats', 'SALib', 'matplotlib') if m in sys.modules))")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout == "[]\n"


#: What ``prp3mc COMMAND --help`` must not import: together about two CPU-seconds (numba alone over one).
HEAVY = ("numba", "scipy", "pandas", "matplotlib", "SALib", "jinja2", "openturns", "dask")


def _commands() -> list[str]:
    from prp3mc.cli import _command_modules
    return sorted(_command_modules())


def test_every_command_is_checked():
    assert {"allocate", "discrepancy", "montecarlo", "sobol", "study", "worstcase"} <= set(_commands())


@pytest.mark.parametrize("command", [*_commands(), None])
def test_help_imports_no_heavy_library(command):
    """``prp3mc COMMAND --help`` (and ``prp3mc --help``) as a user runs it, in a process of its own: it prints its
    help and imports none of :data:`HEAVY` (the command's analyses are imported when it runs). Measured: 2.2-2.35
    CPU-seconds before (allocate, study, sobol...: numba, scipy and pandas through the analyses), 0.3-0.46 after."""
    argv = [command, "--help"] if command else ["--help"]
    code = ("import atexit, sys\n"
            f"atexit.register(lambda: print('HEAVY', sorted(m for m in {HEAVY!r} if m in sys.modules)))\n"
            f"from prp3mc.cli import main\nsys.exit(main({argv!r}))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert "usage: prp3mc" in run.stdout and run.stdout.rstrip().endswith("HEAVY []"), run.stdout[-300:]


def test_z95_is_the_normal_quantile():
    from prp3mc.units import Z95, z_value
    assert Z95 == z_value(0.95)
