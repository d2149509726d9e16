"""Work on a forked process (prp3mc._fork): the same value as here, errors and warnings raised here."""

import os
import signal
import threading
import time
import warnings

import numpy as np
import pytest

import prp3mc._fork as fork

forks = pytest.mark.skipif(not hasattr(os, "fork"), reason="the system cannot fork")
READY = {}


def _prepare():
    READY["pid"] = os.getpid()


def _work(k, text):
    warnings.warn(f"said by the work: {text}", UserWarning)
    return {"value": np.arange(6.0) ** k, "pid": os.getpid(), "prepared": READY.get("pid")}


@forks
@pytest.mark.parametrize("processes", [1, 2])
def test_the_value_is_the_same_there_and_here(processes, monkeypatch):
    monkeypatch.setattr(fork, "fork_workers", lambda n: min(n, processes))
    READY.clear()
    with pytest.warns(UserWarning, match="said by the work: hello"):
        with fork.in_background(_work, prepare=_prepare) as job:
            assert job.forked == (processes == 2)
            job.submit(2, "hello")
            got = job.result()
    assert np.array_equal(got["value"], np.arange(6.0) ** 2)
    there = processes == 2
    assert (got["pid"] != os.getpid()) == there
    assert got["prepared"] == (got["pid"] if there else None)     # prepared there, where there is a there


def _fails(*args):
    raise ValueError("bad input, one line")


@forks
def test_an_error_there_is_raised_here(monkeypatch):
    monkeypatch.setattr(fork, "fork_workers", lambda n: 2)
    with fork.in_background(_fails) as job:
        job.submit(1)
        with pytest.raises(ValueError, match="bad input, one line"):
            job.result()


@forks
def test_arguments_that_cannot_go_there_are_used_here(monkeypatch):
    monkeypatch.setattr(fork, "fork_workers", lambda n: 2)
    with fork.in_background(_work) as job:
        job.submit(1, lambda: None)              # a lambda does not pickle: computed here
        with pytest.warns(UserWarning):
            assert job.result()["pid"] == os.getpid()


@forks
def test_leaving_without_the_result_ends_the_process(tmp_path, monkeypatch):
    monkeypatch.setattr(fork, "fork_workers", lambda n: 2)
    marker = tmp_path / "pid"

    def sleeper():
        marker.write_text(str(os.getpid()))
        time.sleep(600)

    with fork.in_background(sleeper) as job:
        job.submit()
        while not marker.exists() or not marker.read_text():
            time.sleep(0.01)
    with pytest.raises(ProcessLookupError):   # killed and reaped: no such process any more
        os.kill(int(marker.read_text()), 0)


def test_never_forks_while_another_thread_runs():
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        assert fork.fork_workers(12) == 1
        with fork.in_background(_work) as job:
            assert not job.forked
            job.submit(1, "here")
            with pytest.warns(UserWarning):
                assert job.result()["pid"] == os.getpid()
    finally:
        stop.set()
        other.join()


def _gone(pid: int) -> bool:
    """Whether process ``pid`` ended (a zombie left for its new parent to reap counts as ended)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0] == b"Z"
    except FileNotFoundError:
        return True


def _wait_until(condition, seconds: float = 20.0) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(0.02)
    return condition()


def _in_thread(fn, seconds: float = 60.0):
    """``fn()`` on a daemon thread, or None if it did not return in time (a hang fails the test, not the run)."""
    box = []
    t = threading.Thread(target=lambda: box.append(fn()), daemon=True)
    t.start()
    t.join(seconds)
    return box[0] if box else None


def _pool_then_wait(caller: int, marker: str):
    """There: start a pool of two workers (as a report's drawing job does) and wait; here: 'here'."""
    if os.getpid() == caller:
        return "here"
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("fork"), initializer=fork.forked_start,
                             initargs=(os.getpid(),)) as pool:
        pids = set(pool.map(_worker_pid, range(8)))
        with open(marker, "w") as f:
            f.write(" ".join(map(str, pids)))
        time.sleep(600)


def _worker_pid(_):
    time.sleep(0.05)
    return os.getpid()


@forks
@pytest.mark.skipif(not os.path.exists("/proc/self/stat"), reason="needs /proc")
def test_a_job_killed_while_its_workers_run_is_done_here_and_leaves_no_process(tmp_path, monkeypatch):
    """Its pool's workers die with it and hold none of its pipes: the caller sees the end at once."""
    monkeypatch.setattr(fork, "fork_workers", lambda n: 2)
    marker = tmp_path / "pids"
    with fork.in_background(_pool_then_wait) as job:
        job.submit(os.getpid(), str(marker))
        assert _wait_until(lambda: marker.exists() and marker.read_text())
        workers = [int(p) for p in marker.read_text().split()]
        os.kill(job._pid, signal.SIGKILL)
        assert _in_thread(job.result) == "here"
    assert _wait_until(lambda: all(_gone(p) for p in workers)), "a worker outlived its job"


@forks
def test_no_process_to_be_had_computes_here_and_leaks_nothing(monkeypatch):
    monkeypatch.setattr(fork, "fork_workers", lambda n: 2)

    def no_fork():
        raise BlockingIOError(11, "Resource temporarily unavailable")

    monkeypatch.setattr(fork.os, "fork", no_fork)
    before = set(os.listdir("/proc/self/fd")) if os.path.exists("/proc/self/fd") else set()
    with pytest.warns(UserWarning):
        with fork.in_background(_work) as job:
            assert not job.forked
            job.submit(1, "here")
            assert job.result()["pid"] == os.getpid()
    if before:
        assert set(os.listdir("/proc/self/fd")) == before


@forks
def test_a_later_job_holds_no_pipe_of_an_earlier_one(monkeypatch):
    """Job a's arguments do not go there (a lambda does not pickle): its process sees the end of its pipe
    at once and a's value is computed here, although job b was forked after a's pipes were made."""
    monkeypatch.setattr(fork, "fork_workers", lambda n: 2)
    with fork.in_background(_work) as a, fork.in_background(_work) as b:
        a.submit(1, lambda: None)
        with pytest.warns(UserWarning):
            got = _in_thread(a.result)
        assert got is not None and got["pid"] == os.getpid()
        b.submit(2, "there")
        with pytest.warns(UserWarning):
            assert b.result()["pid"] != os.getpid()


def test_cores_numbered_otherwise_are_unknown_not_idle(monkeypatch):
    """Where /proc/stat has no row for a core of the affinity (a container's renumbered view), the
    measure is unknown (the load average decides), not 'no other process is busy'."""
    monkeypatch.setattr(fork.os, "sched_getaffinity", lambda pid: {4096}, raising=False)
    assert fork._Meter()._sample() is None
