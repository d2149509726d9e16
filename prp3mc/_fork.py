"""Work on forked processes while a core is idle.

Where the operating system can fork (Linux), a forked process inherits
everything in memory, so independent work (a report's figures, a stage of an
analysis) can run on another core with nothing pickled but its arguments
and its result. :func:`fork_workers` says how many processes pay;
:func:`in_background` starts one at once, so that it can get ready (import
what it needs) while the caller computes its arguments. The numbers are the
same either way: the work is the same code on the same data.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import pickle
import signal
import struct
import sys
import threading
import time
import warnings
from typing import Callable, Iterator

from ._threads import cores

__all__ = ["fork_workers", "in_background", "Background", "forked_start"]

_SIZE = struct.Struct("<Q")           # each message: its length, then its pickle
_PR_SET_PDEATHSIG = 1


def fork_workers(n_tasks: int) -> int:
    """Processes for ``n_tasks``: 1 plus the idle cores (rounded), at most ``n_tasks`` and the cores, where the
    system can fork; else 1.

    A core is idle when other processes leave it so: the busy time of this
    process's cores (``/proc/stat``) less this process's own CPU time (its
    threads and its children, :class:`_Meter`), over the time since the
    previous decision or since this module was imported, leaves at least half
    a core free besides this process's own. Where that cannot be read, while
    the 1-minute load average is below the cores (it counts this process,
    and lags: after a run it still counts that run).

    On the 2-core development machine shared with other jobs, forked
    processes (the discrepancy command's accuracy and figures) made a run
    2.5-3.4 s instead of 3.6-4.3 s when the other core was free, and
    4.4-5.6 s instead of 4.4-4.9 s when another job kept it busy; two workers
    drew the paper study's figures 1.4 times faster at load 2.3 and slower at
    4.4 (``benchmarks/bench_study.py``): with every core busy they only add
    processes competing for it.

    A process with other Python threads running (a notebook kernel, a Dask
    worker) never forks: a fork copies only the calling thread, and a lock
    another thread held stays held in the child. (Threads of native libraries
    are not seen: OpenBLAS, the one prp3mc's processes start, mends itself at
    a fork.)
    """
    if not sys.platform.startswith("linux"):
        return 1
    if threading.active_count() > 1:
        return 1
    n = cores()
    busy = _METER.busy_elsewhere()
    if busy is None:
        return max(1, min(n_tasks, n)) if os.getloadavg()[0] < n else 1
    return max(1, min(n_tasks, n, 1 + int(n - 1 - busy + 0.5)))


class _Meter:
    """Cores kept busy by other processes than this one and its children, from ``/proc/stat`` (Linux)."""

    #: Shortest window (s) measured; a decision sooner after the previous one reuses its measure.
    WINDOW = 0.2

    def __init__(self):
        self.children: set = set()          # running forked processes, whose CPU time is this process's
        self.busy = None
        self.last = self._sample()

    def _sample(self) -> tuple[float, float, float] | None:
        """(time, busy CPU-s of this process's cores since boot, this process's CPU-s), or None."""
        try:
            names = {f"cpu{c}" for c in os.sched_getaffinity(0)}
            with open("/proc/stat", "rb") as f:
                rows = [line.split() for line in f.read().decode().splitlines() if line.split(" ", 1)[0] in names]
            if len(rows) != len(names):     # numbered otherwise (a container's view of the host): unknown
                return None
            busy = sum(int(r[1]) + int(r[2]) + int(r[3]) + int(r[6]) + int(r[7]) + int(r[8]) for r in rows)
            own = sum(os.times()[:4])
            for pid in self.children:       # user, system and waited-for children's times, in clock ticks
                with open(f"/proc/{pid}/stat", "rb") as f:
                    own += sum(int(v) for v in f.read().rsplit(b")", 1)[1].split()[11:15]) / _TICKS
        except (OSError, ValueError, IndexError, AttributeError):
            return None
        return time.monotonic(), busy / _TICKS, own

    def busy_elsewhere(self) -> float | None:
        """Cores other processes kept busy since the previous measure (None where ``/proc`` cannot be read)."""
        now = self._sample()
        if now is None or self.last is None:
            return None
        if now[0] - self.last[0] < self.WINDOW and self.busy is not None:
            return self.busy
        self.busy = max(0.0, ((now[1] - self.last[1]) - (now[2] - self.last[2])) / max(now[0] - self.last[0], 1e-3))
        self.last = now
        return self.busy


_TICKS = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
_METER = _Meter()


def _message(obj) -> bytes:
    """``obj`` pickled, behind its length."""
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    return _SIZE.pack(len(data)) + data


def _write(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _read(fd: int, n: int) -> bytes:
    """Up to ``n`` bytes from ``fd``: fewer only where the writer closed it first."""
    chunks = []
    while n > 0:
        chunk = os.read(fd, min(n, 1 << 20))
        if not chunk:
            break
        chunks.append(chunk)
        n -= len(chunk)
    return b"".join(chunks)


def _receive(fd: int):
    """The object a :func:`_message` brought through ``fd``; ValueError where it broke off."""
    head = _read(fd, _SIZE.size)
    if len(head) < _SIZE.size:
        raise ValueError("nothing came through the pipe")
    size = _SIZE.unpack(head)[0]
    data = _read(fd, size)
    if len(data) < size:
        raise ValueError("the message broke off")
    return pickle.loads(data)


def _widen(fd: int) -> None:
    """Let a writer put up to 1 MiB into the pipe ``fd`` without waiting for the reader (Linux)."""
    with contextlib.suppress(AttributeError, OSError):
        import fcntl
        fcntl.fcntl(fd, fcntl.F_SETPIPE_SZ, 1 << 20)


#: The ends of the :class:`Background` pipes this process holds: a process forked from it closes them all
#: (:func:`forked_start`), so that a pipe ends when the processes it joins end, whatever else was forked.
_PIPES: set = set()


def forked_start(parent: int) -> None:
    """The start of every process forked here (a :class:`Background` job, a worker of its pool): it ends when
    its parent ends, and closes the pipe ends it inherited from other jobs.

    Without that, a worker forked by a job's process would hold the job's
    pipe to the caller open, and the caller would wait for ever for a job
    killed while drawing; and a worker would outlive a run interrupted there.
    """
    with contextlib.suppress(AttributeError, OSError):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:            # the parent ended before the request took effect
        os._exit(1)
    for fd in _PIPES:
        with contextlib.suppress(OSError):
            os.close(fd)
    _PIPES.clear()
    signal.signal(signal.SIGTERM, signal.SIG_DFL)   # a terminate() ends it: the caller's handler is the caller's


def _child(fn: Callable, prepare: Callable | None, parent: int, args_fd: int, value_fd: int) -> None:
    """In the forked process: ``prepare()``, then ``fn(*args)`` on the arguments sent, its value and warnings sent
    back; never returns."""
    global _METER
    code = 1
    try:
        forked_start(parent)
        _PIPES.update((args_fd, value_fd))      # closed in whatever this process forks in turn
        _METER = _Meter()                       # this process's own times start at the fork
        if prepare is not None:
            prepare()
        args = _receive(args_fd)
        with warnings.catch_warnings(record=True) as caught:
            value = fn(*args)
        _write(value_fd, _message((value, [(w.message, w.category, w.filename, w.lineno) for w in caught])))
        code = 0
    finally:
        os._exit(code)  # no interpreter exit: the caller's buffers, atexit and finally blocks are the caller's


class Background:
    """``fn(*args)`` on a forked process, started before its arguments are known (see :func:`in_background`)."""

    def __init__(self, fn: Callable, prepare: Callable | None = None):
        self.fn, self.args = fn, ()
        self._pid = self._args_fd = self._value_fd = None
        if fork_workers(2) < 2:
            return
        parent = os.getpid()
        args_read, args_write = os.pipe()
        value_read, value_write = os.pipe()
        for stream in (sys.stdout, sys.stderr):   # else what they buffer would be written twice, or lost
            with contextlib.suppress(AttributeError, OSError, ValueError):
                stream.flush()
        try:
            pid = os.fork()
        except OSError:                           # no process to be had (a limit, memory): fn runs here
            for fd in (args_read, args_write, value_read, value_write):
                os.close(fd)
            return
        if pid == 0:
            os.close(args_write)
            os.close(value_read)
            _child(fn, prepare, parent, args_read, value_write)
        os.close(args_read)
        os.close(value_write)
        _widen(args_write)
        self._pid, self._args_fd, self._value_fd = pid, args_write, value_read
        _PIPES.update((args_write, value_read))
        _METER.children.add(pid)

    @property
    def forked(self) -> bool:
        """Whether ``fn`` runs on a forked process (until its result is collected)."""
        return self._pid is not None

    def submit(self, *args) -> None:
        """Hand ``fn`` its arguments: it starts there now (here, it waits for :meth:`result`). The call
        returns once the pipe took them all: at once for up to 1 MiB."""
        self.args = args
        if self._args_fd is not None:
            fd, self._args_fd = self._args_fd, None
            try:
                _write(fd, _message(args))
            except Exception:       # unpicklable, or the process is gone: result() computes here
                pass
            finally:
                _PIPES.discard(fd)
                os.close(fd)

    def result(self):
        """``fn(*args)``: the forked process's value, or computed here where it gave none (``fn`` raised
        there, the process was killed, or its value did not come back whole): an error of ``fn``'s is then
        raised here, with its traceback, after the work was done twice. Warnings ``fn`` gave there are
        given again here."""
        if self._pid is None:
            return self.fn(*self.args)
        if self._args_fd is not None:       # never submitted: fn()
            self.submit(*self.args)
        try:
            value, shown = _receive(self._value_fd)
        except Exception:
            value = shown = None
        self.close(wait=True)
        if shown is None:
            return self.fn(*self.args)
        for message, category, filename, lineno in shown:
            warnings.warn_explicit(message, category, filename, lineno)
        return value

    def close(self, wait: bool = False) -> None:
        """Release the pipes and end the forked process (``wait``: for it to end by itself)."""
        for fd in (self._args_fd, self._value_fd):
            if fd is not None:
                _PIPES.discard(fd)
                os.close(fd)
        self._args_fd = self._value_fd = None
        if self._pid is not None:
            pid, self._pid = self._pid, None
            if not wait:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
            with contextlib.suppress(ChildProcessError):    # SIGCHLD ignored: the system reaped it
                os.waitpid(pid, 0)              # its CPU time now counts among this process's children's
            _METER.children.discard(pid)


@contextlib.contextmanager
def in_background(fn: Callable, *, prepare: Callable | None = None) -> Iterator[Background]:
    """Fork a process for ``fn`` now, while a core is idle; yields a :class:`Background`.

    The process runs ``prepare()`` at once (say, imports), then waits for
    :meth:`Background.submit` to hand it ``fn``'s arguments;
    :meth:`Background.result` returns ``fn(*args)``. Where no process is
    forked (:func:`fork_workers` gives no second process), or it gave
    nothing back (``fn`` raised, or it was killed), ``result()`` calls
    ``fn(*args)`` here: the value is the same, and an error is raised here
    with its traceback. Leaving the block ends the process if its result was
    not asked for; it also ends with its parent, and so do the processes it
    forks that call :func:`forked_start` (a pool's initializer).
    """
    job = Background(fn, prepare)
    try:
        yield job
    finally:
        job.close()
