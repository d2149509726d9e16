"""Drawing and saving a report's figures, here or on worker processes.

By default :func:`rendering` draws the figures in this process, one after
the other, as the caller consumes them. Asked for ``workers``, it hands them
to a :class:`concurrent.futures.ProcessPoolExecutor` with the ``fork`` start
method, whose workers inherit the results in memory (only each figure's index
and its PNG bytes cross between processes) while the caller goes on (writing
tables); where the system cannot fork or another thread runs (a fork copies
only the calling thread: a notebook kernel, a Dask worker), they are drawn
here. The files and bytes are the same either way. Workers are not the
default: on the shared 2-core machine (load 12) the discrepancy command took
20-35 s with two drawing workers and 19.5-26.6 s without (three turns of
each, issue 23); on idle cores they pay, but less than 2x.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Callable, Iterator, Sequence

from ..output import save_figure

__all__ = ["rendering"]

#: (file name, a callable that draws the figure and returns it)
FigureTask = tuple[str, Callable[[], object]]

_TASKS: dict = {}  # what rendering() draws, inherited by its forked workers


def _render(k: int) -> bytes:
    name, draw = _TASKS["figures"][k]
    return save_figure(draw(), _TASKS["folder"], name, _TASKS["formats"], _TASKS["dpi"])


def _worker_start(parent: int) -> None:
    """A worker leaves interruptions to the caller, which ends the pool (Ctrl-C is ignored, SIGTERM ends it),
    and ends when ``parent`` does: a caller killed outright leaves no worker holding its output folder's lock."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    threading.Thread(target=_end_with, args=(parent,), daemon=True).start()


def _end_with(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(0.5)
    os._exit(1)


def _can_fork() -> bool:
    return "fork" in multiprocessing.get_all_start_methods() and threading.active_count() == 1


@contextlib.contextmanager
def rendering(figures: Sequence[FigureTask], folder: str | os.PathLike, formats=("png",),
              workers: int = 1, dpi: int = 150) -> Iterator[Iterator[bytes]]:
    """Draw every figure and save it as ``folder/name.<format>``; yields an iterator of their PNG bytes, in order.

    Parameters
    ----------
    figures : sequence of (name, draw)
        ``draw()`` returns a Figure (on an Agg canvas of its own).
    folder : path
    formats : sequence of str
        As :func:`prp3mc.output.save_figure`.
    workers : int
        Worker processes (at most one per figure), where the system can fork
        and no other thread runs; 1 (default) draws in this process, lazily,
        as the iterator is consumed.
    dpi : int
        Resolution of every format (:func:`prp3mc.output.save_figure`).

    With workers, drawing starts on entry and the caller can do other work
    before consuming the iterator; leaving the block waits for every figure
    (leaving it by an error cancels those not started).
    """
    figures, folder, formats = list(figures), Path(folder), tuple(formats)
    workers = min(len(figures), int(workers))
    if workers <= 1 or not _can_fork():
        yield (save_figure(draw(), folder, name, formats, dpi) for name, draw in figures)
        return
    import matplotlib.backends.backend_agg  # noqa: F401  once here, inherited by every worker
    _TASKS.update(figures=figures, folder=folder, formats=formats, dpi=dpi)
    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork"), initializer=_worker_start,
                               initargs=(os.getpid(),))
    try:
        futures = [pool.submit(_render, k) for k in range(len(figures))]
        yield (future.result() for future in futures)
    except BaseException:
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    else:
        pool.shutdown(wait=True)
    finally:
        _TASKS.clear()
