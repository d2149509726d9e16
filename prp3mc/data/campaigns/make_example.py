"""Write example.csv beside this file: the campaign ``--data example`` reads (README, *Discrepancy*).

A u-shape machine with the paper's budget and two hidden effects (lead error
``scale_2`` 5e-4, backlash ``backlash_1`` 20 µm), measured by an instrument
registered 20 µm / 0.005 deg off, with 2 µm and 0.0005 deg of noise: 49 poses
over the u-shape test region, 8 visits each. Run from the repository root::

    python prp3mc/data/campaigns/make_example.py

It runs ``prp3mc simulate`` with seed 2026, so the file is what that command writes.
"""

import subprocess
import sys
from pathlib import Path

SEED = 2026


def command(out: Path) -> list[str]:
    """The ``prp3mc`` command line that writes the example campaign to ``out``."""
    return ["simulate", "--geometry", "u-shape", "--budget", "paper", "--poses", "49", "--visits", "8",
            "--effects", "scale_2=5e-4,backlash_1=0.02", "--registration", "0.02,-0.02,0.005",
            "--instrument-sigma-mm", "0.002", "--instrument-sigma-deg", "0.0005", "--seed", str(SEED),
            "--out", str(out), "--force"]


if __name__ == "__main__":
    sys.exit(subprocess.run([sys.executable, "-m", "prp3mc", *command(Path(__file__).with_name("example.csv"))]).returncode)
