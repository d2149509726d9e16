"""Drawing and saving a report's figures, on worker processes where that pays.

Matplotlib draws on one core, and a report's figures are independent: where
the operating system can fork (Linux), :func:`rendering` draws them on one
worker process per core while a core is idle, and the caller goes on
(writing tables). Forked workers inherit the results in memory: nothing is
pickled but each figure's index and its PNG bytes. Elsewhere, or with one
core, the figures are drawn here, one after the other. The files and bytes
are the same either way (``benchmarks/bench_study.py`` times both).
:func:`preloading` imports matplotlib on a thread while a command's analyses
run, so that drawing starts at once.
"""

from __future__ import annotations

import contextlib
import gc
import multiprocessing
import os
import sys
import threading
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Callable, Iterator, Sequence

from ..output import save_figure

__all__ = ["rendering", "default_workers", "preloading"]

#: (file name, a callable that draws the figure and returns it)
FigureTask = tuple[str, Callable[[], object]]

_TASKS: dict = {}  # in a worker process: what rendering() handed it at the fork


def default_workers(n_figures: int) -> int:
    """Worker processes for ``n_figures``: one per core while some core is idle, where the system can fork; else 1.

    A core is taken as idle while the 1-minute load average is below the
    cores this process may use. On the 2-core development machine shared
    with other jobs, two workers drew the paper study's figures 1.4 times
    faster than one process at load 2.3, and slower at load 4.4
    (``benchmarks/bench_study.py``): with every core busy they only add
    processes competing for it. The files are the same either way.

    A process with other threads running (a notebook kernel, a Dask worker)
    never forks: a fork copies only the calling thread, and a lock another
    thread held stays held in the child.
    """
    if not sys.platform.startswith("linux") or "fork" not in multiprocessing.get_all_start_methods():
        return 1
    if threading.active_count() > 1:
        return 1
    cores = len(os.sched_getaffinity(0))
    return max(1, min(n_figures, cores)) if os.getloadavg()[0] < cores else 1


def _import_drawing() -> None:
    """Import what drawing a report's figures needs, and load its font."""
    import matplotlib.backends.backend_agg  # noqa: F401
    import matplotlib.figure  # noqa: F401 -- (the Agg backend no longer imports it)
    import PIL.PngImagePlugin  # noqa: F401 -- (imported by the first PNG written)
    from ._layout import text_inches
    text_inches("0")


@contextlib.contextmanager
def preloading(enabled: bool = True) -> Iterator[None]:
    """Import what drawing the figures needs on a thread while the block runs; the thread is joined at its end.

    Matplotlib takes about half a second to import, on one core: a command
    that writes a report after its analyses (which leave a core idle part
    of the time) imports it meanwhile. Nothing is imported twice: the
    report's figures then start at once (:func:`rendering`). The thread is
    joined when the block ends, so it never runs when the figures' worker
    processes fork. ``enabled=False`` runs the block alone.
    """
    thread = threading.Thread(target=_import_drawing, name="prp3mc-preload", daemon=True) if enabled else None
    if thread is not None:
        thread.start()
    try:
        yield
    finally:
        if thread is not None:
            thread.join()


def _render(k: int) -> bytes:
    name, draw = _TASKS["figures"][k]
    return save_figure(draw(), _TASKS["folder"], name, _TASKS["formats"])


def _inherit(figures, folder, formats) -> None:
    _TASKS.update(figures=figures, folder=folder, formats=formats)


@contextlib.contextmanager
def rendering(figures: Sequence[FigureTask], folder: str | os.PathLike, formats=("png",),
              workers: int | None = None) -> Iterator[Iterator[bytes]]:
    """Draw every figure and save it as ``folder/name.<format>``; yields an iterator of their PNG bytes, in order.

    Parameters
    ----------
    figures : sequence of (name, draw)
        ``draw()`` returns a Figure (on an Agg canvas of its own).
    folder : path
    formats : sequence of str
        As :func:`prp3mc.output.save_figure`.
    workers : int, optional
        Worker processes (default :func:`default_workers`); 1 draws in this
        process, lazily, as the iterator is consumed.

    With workers, drawing starts on entry and the caller can do other work
    before consuming the iterator; leaving the block waits for every figure.

    Inside the block the objects that exist on entry (the libraries'
    modules, the results) are frozen out of the garbage collector
    (:func:`gc.freeze`): a figure leaves tens of thousands of objects in
    reference cycles, and each full collection they trigger would walk those
    too (a tenth of a second each), in this process and, copying their pages,
    in every worker. They are unfrozen when the block ends.
    """
    figures, folder = list(figures), Path(folder)
    workers = default_workers(len(figures)) if workers is None else max(1, int(workers))
    if workers > 1:
        _import_drawing()                   # once here (if not preloaded), inherited, not in every worker
    gc.freeze()
    try:
        if workers == 1:
            yield (save_figure(draw(), folder, name, formats) for name, draw in figures)
            return
        with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("fork"),
                                 initializer=_inherit, initargs=(figures, folder, tuple(formats))) as pool:
            yield pool.map(_render, range(len(figures)))
    finally:
        gc.unfreeze()
