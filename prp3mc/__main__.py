"""``python -m prp3mc`` runs the command line."""

import sys

from .cli import main

if __name__ == "__main__":          # not on import (e.g. by the documentation build walking the package)
    sys.exit(main())
