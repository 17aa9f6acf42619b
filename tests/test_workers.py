"""Worker processes end with the process that started them (vgpl.workers)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from vgpl.workers import worker_pool

pytestmark = pytest.mark.slow  # each test starts processes

# a parent that starts one worker, prints the worker's pid, queues a long task and waits
PARENT = textwrap.dedent("""
    import os, time
    from vgpl.workers import worker_pool
    pool = worker_pool(1)
    print(pool.submit(os.getpid).result(), flush=True)
    pool.submit(time.sleep, 120)
    time.sleep(120)
""")


def running(pid: int) -> bool:
    """Whether process ``pid`` exists and has not ended (a zombie waiting to be reaped has ended)."""
    if Path("/proc/self").exists():  # Linux: the state letter after the command name
        try:
            return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
        except FileNotFoundError:
            return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_a_worker_ends_within_seconds_of_its_parent_being_killed(sig):
    parent = subprocess.Popen([sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True)
    worker = None
    try:
        worker = int(parent.stdout.readline())
        assert worker != parent.pid and running(worker)
        time.sleep(1.5)  # the worker is now inside its 120-s task
        assert running(worker)
        parent.send_signal(sig)
        parent.wait(timeout=10)
        deadline = time.monotonic() + 10
        while running(worker) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not running(worker), f"worker {worker} still running 10 s after its parent got {sig.name}"
    finally:
        parent.kill()
        if worker is not None and running(worker):  # the watch failed: do not leave the worker for its 120 s
            os.kill(worker, signal.SIGKILL)


def mark_worker() -> None:
    os.environ["VGPL_TEST_WORKER_INITIALISED"] = "yes"


def worker_state() -> tuple[int, str | None]:
    return os.getpid(), os.environ.get("VGPL_TEST_WORKER_INITIALISED")


def test_the_pool_runs_its_initializer_in_every_worker_and_returns_results():
    with worker_pool(2, mark_worker) as pool:
        states = [job.result() for job in [pool.submit(worker_state) for _ in range(6)]]
    assert {flag for _, flag in states} == {"yes"}
    assert os.getpid() not in {pid for pid, _ in states}
    assert "VGPL_TEST_WORKER_INITIALISED" not in os.environ
