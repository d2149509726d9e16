"""Work on a forked process (prp3mc._fork): the same value as here, errors and warnings raised here."""

import os
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
