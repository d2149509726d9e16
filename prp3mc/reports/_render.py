"""Drawing and saving a report's figures, on worker processes where that pays.

Matplotlib draws on one core, and a report's figures are independent: where
the operating system can fork (Linux), :func:`rendering` draws them on a
few worker processes while cores are idle (:func:`prp3mc._fork.fork_workers`),
and the caller goes on (writing tables). Forked workers inherit the results
in memory: nothing is pickled but each figure's index and its PNG bytes
(handed to a process made ready beforehand, :func:`drawing_ahead`, the
figures' callables and what they draw are pickled once). Elsewhere, or with one
core, the figures are drawn here, one after the other. The files and bytes
are the same either way (``benchmarks/bench_study.py`` times both).
"""

from __future__ import annotations

import contextlib
import gc
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Callable, Iterator, Sequence

from .._fork import Background, fork_workers, forked_start, in_background
from ..output import save_figure

__all__ = ["rendering", "drawing_ahead"]

#: (file name, a callable that draws the figure and returns it)
FigureTask = tuple[str, Callable[[], object]]

_TASKS: dict = {}  # in a worker process: what rendering() handed it at the fork


def _render(k: int) -> bytes:
    name, draw = _TASKS["figures"][k]
    return save_figure(draw(), _TASKS["folder"], name, _TASKS["formats"], _TASKS["dpi"])


def _inherit(parent, figures, folder, formats, dpi) -> None:
    """A worker's start: it ends with ``parent`` (:func:`prp3mc._fork.forked_start`), what it draws, and
    every object it inherited frozen out of its garbage collector.

    A figure leaves tens of thousands of objects in reference cycles; the
    full collections they trigger would otherwise walk every inherited
    object too (a tenth of a second each), copying their pages.
    """
    forked_start(parent)
    gc.freeze()
    _TASKS.update(figures=figures, folder=folder, formats=formats, dpi=dpi)


def _import_matplotlib() -> None:
    """Import what drawing on Agg and writing PNG need, and load the font (the Agg backend no longer imports
    matplotlib.figure; PIL's PNG writer comes with the first PNG written)."""
    import matplotlib.backends.backend_agg, matplotlib.figure, PIL.PngImagePlugin  # noqa: F401,E401
    from ._layout import text_inches
    text_inches("0")


def _drawn(figures: list, folder: Path, formats: tuple, workers: int | None, dpi: int) -> list[bytes]:
    with rendering(figures, folder, formats, workers, dpi) as pngs:
        return list(pngs)


def drawing_ahead() -> contextlib.AbstractContextManager[Background]:
    """A process for a report's figures, forked now where a core is idle: it imports matplotlib (about
    0.45 s) while the caller computes what to draw, then draws what :func:`rendering` hands it (``ahead=``).

    A context manager (:func:`prp3mc._fork.in_background`); without a forked process the figures are
    drawn as :func:`rendering` draws them without ``ahead``.
    """
    return in_background(_drawn, prepare=_import_matplotlib)


def _later(get: Callable[[], list]) -> Iterator[bytes]:
    yield from get()


@contextlib.contextmanager
def rendering(figures: Sequence[FigureTask], folder: str | os.PathLike, formats=("png",),
              workers: int | None = None, dpi: int = 150, ahead: Background | None = None
              ) -> Iterator[Iterator[bytes]]:
    """Draw every figure and save it as ``folder/name.<format>``; yields an iterator of their PNG bytes, in order.

    Parameters
    ----------
    figures : sequence of (name, draw)
        ``draw()`` returns a Figure (on an Agg canvas of its own).
    folder : path
    formats : sequence of str
        As :func:`prp3mc.output.save_figure`.
    workers : int, optional
        Worker processes (default :func:`prp3mc._fork.fork_workers`: 1 plus
        the idle cores); 1 draws in this process, lazily, as the iterator is consumed.
    dpi : int
        Resolution of every format (:func:`prp3mc.output.save_figure`).
    ahead : Background, optional
        A process made ready beforehand (:func:`drawing_ahead`): the figures
        are drawn there (on ``workers`` worker processes of its own), and the
        iterator waits for all of them.

    With workers, drawing starts on entry and the caller can do other work
    before consuming the iterator; leaving the block waits for every figure
    (with ``ahead``, consuming the iterator does; leaving early ends that process).
    """
    figures, folder = list(figures), Path(folder)
    workers = fork_workers(len(figures)) if workers is None else max(1, int(workers))
    if ahead is not None:
        ahead.submit(figures, folder, tuple(formats), workers, dpi)
        yield _later(ahead.result)
        return
    if workers == 1:
        yield (save_figure(draw(), folder, name, formats, dpi) for name, draw in figures)
        return
    _import_matplotlib()                   # once here, inherited by every worker
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("fork"),
                             initializer=_inherit, initargs=(os.getpid(), figures, folder, tuple(formats), dpi)
                             ) as pool:
        yield pool.map(_render, range(len(figures)))
