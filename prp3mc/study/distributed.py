"""Running a study's configurations on a Dask cluster (``prp3mc study FILE --scheduler ...``, SPEC §8).

The only module of prp3mc that imports Dask, and only when a
:class:`DaskExecutor` is entered: the serial path never loads it. Dask is an
optional extra (``pip install 'prp3mc[dask]'``).

Scheduler specs:

- ``local:N`` — a ``dask.distributed.LocalCluster`` of N worker processes with
  one thread each, started for the run and closed after it;
- ``tcp://HOST:PORT`` — an existing Dask scheduler. Dask's other schemes
  (``tls://``, ``ucx://``, ``inproc://``, ``ws://``) are refused in one line:
  each needs what a command line cannot give it (certificates, a library, the
  scheduler's own process).

Each configuration is one task. Its random streams come from the study seed
(:mod:`prp3mc.study.runner`), never from the worker, so the results are the
same whichever worker runs it, and the same as a serial run. A task raising
an exception is retried (``retries``); a worker that dies while running a task
costs that task a rerun elsewhere (the scheduler's ``allowed-failures``,
3 by default); a task lost more often than that is reported as failed, with
its parameters, and the other configurations are kept.
"""

from __future__ import annotations

import logging
import re
from typing import Any, Iterable, Iterator

from .._threads import cores
from ..errors import MissingDependencyError, Prp3mcError

__all__ = ["DaskExecutor", "parse_scheduler"]

_LOCAL = re.compile(r"^local:([0-9]+)$")
_ADDRESS = re.compile(r"^tcp://(\[[0-9a-fA-F:.]+\]|[A-Za-z0-9_.-]+):([0-9]{1,5})$")
_SCHEME = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]*)://")
#: Why the Dask schemes other than tcp:// are refused (each ended in Dask's own traceback).
_UNSUPPORTED = {"tls": "needs a security context (certificates) that prp3mc does not take",
                "inproc": "is a scheduler inside one process, which a command line cannot reach",
                "ucx": "needs the UCX library and its Dask backend",
                "ws": "needs the websocket backend", "wss": "needs the websocket backend and certificates"}


#: Local worker processes per core at most (each holds a Python with numpy, about 0.15 GB).
_MAX_LOCAL = 4


def parse_scheduler(spec: str) -> tuple[str, Any]:
    """``("local", n_workers)`` or ``("address", spec)``; Prp3mcError (one line) for anything else.

    >>> parse_scheduler("local:4")
    ('local', 4)
    >>> parse_scheduler("tcp://10.0.0.5:8786")
    ('address', 'tcp://10.0.0.5:8786')
    """
    match = _LOCAL.match(spec)
    if match and int(match.group(1)) > _MAX_LOCAL * cores():
        raise Prp3mcError(f"--scheduler {spec} would start {int(match.group(1))} worker processes on {cores()} "
                          f"cores: at most {_MAX_LOCAL * cores()} (a cluster's address for more)")
    if match and int(match.group(1)) >= 1:
        return "local", int(match.group(1))
    if _ADDRESS.match(spec) and 0 < int(_ADDRESS.match(spec).group(2)) < 65536:
        return "address", spec
    scheme = _SCHEME.match(spec)
    if scheme and scheme.group(1).lower() in _UNSUPPORTED:
        raise Prp3mcError(f"--scheduler {spec}: the {scheme.group(1)}:// scheme {_UNSUPPORTED[scheme.group(1).lower()]}; "
                          "give tcp://HOST:PORT (an SSH tunnel for a remote cluster) or local:N")
    raise Prp3mcError(f"--scheduler must be local:N (N >= 1 local workers) or the address of a Dask scheduler "
                      f"such as tcp://HOST:PORT, got {spec!r}")


def _import_distributed():
    try:
        import distributed
    except ImportError:
        raise MissingDependencyError("Dask", "pip install 'prp3mc[dask]'", "--scheduler") from None
    return distributed


class DaskExecutor:
    """Run tasks on a Dask cluster; a context manager that opens and closes the client (and a local cluster).

    Parameters
    ----------
    scheduler : str
        ``local:N`` or a scheduler address (see the module docstring).
    retries : int
        Reruns of a task that raises (dask's ``retries=``).
    memory_limit : str or float
        Per-worker memory limit of a local cluster (dask's ``memory_limit``).
    timeout : float
        Seconds to wait for the scheduler of an existing cluster.
    """

    in_process = False

    def __init__(self, scheduler: str, *, retries: int = 2, memory_limit: "str | float" = "auto",
                 timeout: float = 30.0):
        self.kind, self.target = parse_scheduler(scheduler)
        self.name = scheduler
        self.retries, self.memory_limit, self.timeout = retries, memory_limit, timeout
        self.client = self.cluster = None

    def __enter__(self) -> "DaskExecutor":
        distributed = _import_distributed()
        try:
            if self.kind == "local":
                # no dashboard; the scheduler's own HTTP routes on a free port, so that two runs at once
                # do not contend for 8787 (and warn about it)
                self.cluster = distributed.LocalCluster(
                    n_workers=self.target, threads_per_worker=1, processes=True, dashboard_address=None,
                    scheduler_kwargs={"dashboard_address": ":0"}, memory_limit=self.memory_limit,
                    silence_logs=logging.ERROR)
                self.client = distributed.Client(self.cluster)
            else:
                self.client = distributed.Client(self.target, timeout=self.timeout)
        except OSError as exc:  # no scheduler at that address (TimeoutError is an OSError)
            self.__exit__(None, None, None)
            raise Prp3mcError(f"cannot reach the Dask scheduler at {self.target}: {exc}") from None
        return self

    def __exit__(self, *exc_info) -> None:
        for part in (self.client, self.cluster):
            if part is not None:
                part.close()
        self.client = self.cluster = None

    def map(self, fn, tasks: Iterable[tuple]) -> Iterator[tuple[int, Any]]:
        """``(k, fn(*task_k))`` for every task as it completes, or ``(k, exception)`` if it was lost.

        Every task is submitted at once (``pure=False``: each is run, none is
        deduplicated); results are gathered as they complete and released
        from the cluster at once.
        """
        distributed = _import_distributed()
        futures = {self.client.submit(fn, *task, pure=False, retries=self.retries): k
                   for k, task in enumerate(tasks)}
        for future in distributed.as_completed(futures):
            k = futures.pop(future)
            try:
                yield k, future.result()
            except Exception as exc:  # noqa: BLE001 -- KilledWorker or a task's own error after its retries
                yield k, exc
            finally:
                future.release()
