"""Drawing and saving a report's figures, on worker processes where that pays.

Matplotlib draws on one core, and a report's figures are independent: where
the operating system can fork (Linux), :func:`rendering` draws them on one
worker process per core while a core is idle, and the caller goes on
(writing tables). Forked workers inherit the results in memory: nothing is
pickled but each figure's index and its PNG bytes. Elsewhere, or with one
core, the figures are drawn here, one after the other. The files and bytes
are the same either way (``benchmarks/bench_study.py`` times both).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Callable, Iterator, Sequence

from .._fork import fork_workers as default_workers
from ..output import save_figure

__all__ = ["rendering", "default_workers"]

#: (file name, a callable that draws the figure and returns it)
FigureTask = tuple[str, Callable[[], object]]

_TASKS: dict = {}  # in a worker process: what rendering() handed it at the fork


def _render(k: int) -> bytes:
    name, draw = _TASKS["figures"][k]
    return save_figure(draw(), _TASKS["folder"], name, _TASKS["formats"], _TASKS["dpi"])


def _inherit(figures, folder, formats, dpi) -> None:
    _TASKS.update(figures=figures, folder=folder, formats=formats, dpi=dpi)


@contextlib.contextmanager
def rendering(figures: Sequence[FigureTask], folder: str | os.PathLike, formats=("png",),
              workers: int | None = None, dpi: int = 150) -> Iterator[Iterator[bytes]]:
    """Draw every figure and save it as ``folder/name.<format>``; yields an iterator of their PNG bytes, in order.

    Parameters
    ----------
    figures : sequence of (name, draw)
        ``draw()`` returns a Figure (on an Agg canvas of its own).
    folder : path
    formats : sequence of str
        As :func:`prp3mc.output.save_figure`.
    workers : int, optional
        Worker processes (default :func:`default_workers`, that is
        :func:`prp3mc._fork.fork_workers`: one per core while a core is
        idle); 1 draws in this process, lazily, as the iterator is consumed.
    dpi : int
        Resolution of every format (:func:`prp3mc.output.save_figure`).

    With workers, drawing starts on entry and the caller can do other work
    before consuming the iterator; leaving the block waits for every figure.
    """
    figures, folder = list(figures), Path(folder)
    workers = default_workers(len(figures)) if workers is None else max(1, int(workers))
    if workers == 1:
        yield (save_figure(draw(), folder, name, formats, dpi) for name, draw in figures)
        return
    import matplotlib.backends.backend_agg, matplotlib.figure  # noqa: F401,E401 -- once here, inherited by every worker
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("fork"),
                             initializer=_inherit, initargs=(figures, folder, tuple(formats), dpi)) as pool:
        yield pool.map(_render, range(len(figures)))
