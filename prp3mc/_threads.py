"""prp3mc's own threads: how many, BLAS inside them, and a run's request to stop them.

prp3mc spreads its long loops over threads of its own (chunks of poses and
samples in Monte Carlo, Sobol and the worst case). A matrix product inside
such a thread would start BLAS's own threads on the same cores, which spin
while they wait for work: inside these sections BLAS runs on one thread,
through threadpoolctl (``benchmarks/bench_study.py`` times the study both ways).

A signal reaches the main thread only. When the command line's handler
interrupts a run it also calls :func:`request_stop`: each worker's loop calls
:func:`check_stop` between its steps and ends there, so that the pool the
interrupted main thread waits for as it unwinds (``with ThreadPoolExecutor``)
empties within a step instead of finishing its work.
"""

from __future__ import annotations

import contextlib
import functools
import os
import threading
from typing import Iterator

__all__ = ["single_threaded_blas", "cores", "request_stop", "clear_stop", "stop_requested", "check_stop"]

_STOP = threading.Event()


@functools.cache
def cores() -> int:
    """The CPU cores this process may run on (its affinity, read once): the default number of prp3mc's threads."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Run BLAS (numpy's and scipy's OpenBLAS or MKL) on one thread inside the block; restored after it.

    The numbers are those of any one-thread BLAS run: how BLAS splits a long
    sum between its threads depends on the machine's cores and moves the last
    bit of some results (the paper study's Sobol tables: at most 8e-16
    relative, before this limit, between one and two BLAS threads).
    """
    from threadpoolctl import threadpool_limits
    with threadpool_limits(limits=1, user_api="blas"):
        yield


def request_stop() -> None:
    """Ask every worker thread to end at its next :func:`check_stop` (the run is being interrupted)."""
    _STOP.set()


def clear_stop() -> None:
    """Forget a stop request (at the start of a run)."""
    _STOP.clear()


def stop_requested() -> bool:
    """Whether the run is being interrupted."""
    return _STOP.is_set()


def check_stop() -> None:
    """Raise KeyboardInterrupt if the run is being interrupted: called by worker loops between their steps."""
    if stop_requested():
        raise KeyboardInterrupt("the run is being interrupted")
