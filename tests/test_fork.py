"""Work on a forked process (prp3mc._fork): the same value as here, errors and warnings raised here."""

import os
import threading
import time
import warnings

import numpy as np
import pytest

import prp3mc._fork as fork

forks = pytest.mark.skipif(not hasattr(os, "fork"), reason="the system cannot fork")


def _work():
    warnings.warn("said by the work", UserWarning)
    return {"value": np.arange(6.0) ** 2, "pid": os.getpid()}


@forks
@pytest.mark.parametrize("processes", [1, 2])
def test_the_value_is_the_same_there_and_here(processes, monkeypatch):
    monkeypatch.setattr(fork, "fork_workers", lambda n: min(n, processes))
    with pytest.warns(UserWarning, match="said by the work"):
        with fork.in_background(_work) as result:
            got = result()
    assert np.array_equal(got["value"], np.arange(6.0) ** 2)
    assert (got["pid"] != os.getpid()) == (processes == 2)


def _fails():
    raise ValueError("bad input, one line")


@forks
def test_an_error_there_is_raised_here(monkeypatch):
    monkeypatch.setattr(fork, "fork_workers", lambda n: 2)
    with fork.in_background(_fails) as result:
        with pytest.raises(ValueError, match="bad input, one line"):
            result()


@forks
def test_leaving_without_the_result_ends_the_process(tmp_path, monkeypatch):
    monkeypatch.setattr(fork, "fork_workers", lambda n: 2)
    marker = tmp_path / "pid"

    def sleeper():
        marker.write_text(str(os.getpid()))
        time.sleep(600)

    with fork.in_background(sleeper):
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
        with fork.in_background(_work) as result:
            with pytest.warns(UserWarning):
                assert result()["pid"] == os.getpid()
    finally:
        stop.set()
        other.join()
