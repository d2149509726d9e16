"""Work on forked processes while a core is idle.

Where the operating system can fork (Linux), a forked process inherits
everything in memory, so independent work (a report's figures, a stage of an
analysis) can run on another core with nothing pickled but its result.
:func:`fork_workers` says how many processes pay; :func:`in_background` runs
one function on a forked process while the caller goes on. The numbers are
the same either way: the work is the same code on the same data.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import pickle
import signal
import sys
import threading
import warnings
from typing import Callable, Iterator, TypeVar

__all__ = ["fork_workers", "in_background"]

T = TypeVar("T")


def fork_workers(n_tasks: int) -> int:
    """Processes for ``n_tasks``: one per core while some core is idle, where the system can fork; else 1.

    A core is taken as idle while the 1-minute load average is below the
    cores this process may use. On the 2-core development machine shared
    with other jobs, two workers drew the paper study's figures 1.4 times
    faster than one process at load 2.3, and slower at load 4.4
    (``benchmarks/bench_study.py``): with every core busy they only add
    processes competing for it.

    A process with other threads running (a notebook kernel, a Dask worker)
    never forks: a fork copies only the calling thread, and a lock another
    thread held stays held in the child.
    """
    if not sys.platform.startswith("linux") or "fork" not in multiprocessing.get_all_start_methods():
        return 1
    if threading.active_count() > 1:
        return 1
    cores = len(os.sched_getaffinity(0))
    return max(1, min(n_tasks, cores)) if os.getloadavg()[0] < cores else 1


def _child(fn: Callable[[], object], fd: int) -> None:
    """In the forked process: ``fn()`` and the warnings it gave, pickled into ``fd``; never returns."""
    code = 1
    try:
        with warnings.catch_warnings(record=True) as caught:
            value = fn()
        shown = [(w.message, w.category, w.filename, w.lineno) for w in caught]
        data = pickle.dumps((value, shown), protocol=pickle.HIGHEST_PROTOCOL)
        with os.fdopen(fd, "wb") as pipe:
            pipe.write(data)
        code = 0
    finally:
        os._exit(code)  # no interpreter exit: the caller's buffers, atexit and finally blocks are the caller's


@contextlib.contextmanager
def in_background(fn: Callable[[], T]) -> Iterator[Callable[[], T]]:
    """Start ``fn()`` on a forked process while a core is idle; yields ``result()``, which returns its value.

    Where no process is forked (:func:`fork_workers` gives no second
    process), ``result()`` calls ``fn()`` here. It does so too when the
    forked process gave nothing back (``fn`` raised, or the process was
    killed): an error is then raised here, with its traceback. Warnings
    ``fn`` gave there are given again here. Leaving the block ends the
    forked process if its result was not asked for.
    """
    child = None                                   # (pid, read end of the pipe) while the process runs
    if fork_workers(2) > 1:
        read, write = os.pipe()
        pid = os.fork()
        if pid == 0:
            os.close(read)
            _child(fn, write)
        os.close(write)
        child = (pid, read)

    def collect() -> bytes:
        nonlocal child
        pid, read = child
        child = None
        try:
            with os.fdopen(read, "rb") as pipe:
                return pipe.read()
        finally:
            os.waitpid(pid, 0)

    def result() -> T:
        if child is None:
            return fn()
        try:
            value, shown = pickle.loads(collect())
        except Exception:           # nothing (or not all) came back: the forked process failed
            return fn()
        for message, category, filename, lineno in shown:
            warnings.warn_explicit(message, category, filename, lineno)
        return value

    try:
        yield result
    finally:
        if child is not None:
            os.kill(child[0], signal.SIGKILL)
            collect()
