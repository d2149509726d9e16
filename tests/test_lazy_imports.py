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
