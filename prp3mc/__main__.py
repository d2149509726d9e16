"""``python -m prp3mc`` runs the command line."""

import os
import signal
import sys


def _before_the_run(signum, frame):
    """SIGINT or SIGTERM while the command line is still loading: nothing has started, so end at once
    (exit 130 or 143, one line) instead of a traceback out of an import; the run installs its own handlers."""
    os.write(2, b"prp3mc: interrupted\n" if signum == signal.SIGINT else b"prp3mc: terminated\n")
    os._exit(130 if signum == signal.SIGINT else 143)


if __name__ == "__main__":          # not on import (e.g. by the documentation build walking the package)
    for _signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(_signum, _before_the_run)
    from .cli import main
    sys.exit(main())
