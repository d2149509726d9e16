"""A small progress reporter for long runs, written to stderr.

It stays silent for runs shorter than ``delay`` seconds and when disabled;
by default it is enabled only when stderr is a terminal.
"""

from __future__ import annotations

import sys
import time

__all__ = ["Progress"]


class Progress:
    """Report ``done / total`` with an ETA at most every ``interval`` seconds.

    Parameters
    ----------
    total : int
    label : str
    enabled : bool or None
        None: only if stderr is a terminal.
    delay : float
        Seconds before the first report.
    """

    def __init__(self, total: int, label: str, enabled: bool | None = None,
                 delay: float = 2.0, interval: float = 0.5):
        self.total, self.label = max(int(total), 1), label
        self.enabled = sys.stderr.isatty() if enabled is None else enabled
        self.delay, self.interval = delay, interval
        self.start = self.last = time.perf_counter()
        self.done = 0
        self.shown = False

    def update(self, n: int = 1, label: str | None = None) -> None:
        """Count ``n`` more done; ``label``, if given, replaces the label (e.g. the stage just finished)."""
        self.done += n
        if label is not None:
            self.label = label
        now = time.perf_counter()
        if not self.enabled or now - self.start < self.delay or now - self.last < self.interval:
            return
        self.last = now
        frac = self.done / self.total
        eta = (now - self.start) * (1 - frac) / frac if frac > 0 else float("nan")
        bar = "#" * int(30 * frac)
        sys.stderr.write(f"\r{self.label}: [{bar:<30}] {self.done}/{self.total} "
                         f"{100 * frac:5.1f}%  ETA {eta:6.1f} s")
        sys.stderr.flush()
        self.shown = True

    def close(self) -> None:
        if self.shown:
            elapsed = time.perf_counter() - self.start
            sys.stderr.write(f"\r{self.label}: done {self.total}/{self.total} in {elapsed:.1f} s" + " " * 30 + "\n")
            sys.stderr.flush()

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
