"""The report's figures on worker processes (prp3mc.reports._render): they end with the process that drew them."""

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

#: A run drawing two figures on two workers that write their PIDs and then draw for a minute.
_RUN = textwrap.dedent("""
    import os, sys, time
    from prp3mc.reports._render import rendering

    def draw():
        with open(sys.argv[1], "a") as f:
            f.write(f"{os.getpid()} ")
        time.sleep(60)

    with rendering([("a", draw), ("b", draw)], sys.argv[2], workers=2) as pngs:
        list(pngs)
""")


def _gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"      # a zombie has ended
    except FileNotFoundError:
        return True


def _wait_until(cond, seconds: float = 30.0) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.05)
    return False


@pytest.mark.skipif(not hasattr(os, "fork") or not os.path.exists("/proc/self/stat"), reason="forks, reads /proc")
def test_workers_end_when_the_caller_is_killed_outright(tmp_path):
    """SIGKILL leaves the caller no time to end its pool: the workers see it gone and end within a second or so."""
    pids = tmp_path / "pids"
    run = subprocess.Popen([sys.executable, "-c", _RUN, str(pids), str(tmp_path)])
    try:
        assert _wait_until(lambda: pids.exists() and len(pids.read_text().split()) == 2), "no worker started"
        workers = [int(p) for p in pids.read_text().split()]
        assert run.pid not in workers
    finally:
        run.kill()
        run.wait()
    assert _wait_until(lambda: all(_gone(p) for p in workers), 10.0), "a worker outlived the run that forked it"
