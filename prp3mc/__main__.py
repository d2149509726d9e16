"""``python -m prp3mc`` and the ``prp3mc`` console script run the command line (:func:`main`)."""

import os
import signal
import sys


def _before_the_run(signum, frame):
    """SIGINT or SIGTERM while the command line is still loading: nothing has started, so end at once
    (exit 130 or 143, one line) instead of a traceback out of an import; the run installs its own handlers."""
    os.write(2, b"prp3mc: interrupted\n" if signum == signal.SIGINT else b"prp3mc: terminated\n")
    os._exit(130 if signum == signal.SIGINT else 143)


def main() -> int:
    """Entry point of the ``prp3mc`` console script and of ``python -m prp3mc``; returns the exit status.

    The handlers of SIGINT and SIGTERM come first, before the command line
    (numpy and the command's modules, a few tenths of a second) is imported:
    a signal in that time ends the process with one line, never a traceback.
    """
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, _before_the_run)
    from .cli import main as run
    return run()


if __name__ == "__main__":          # not on import (e.g. by the documentation build walking the package)
    sys.exit(main())
