"""touch2robot.local_server: the servers the command starts cannot outlive it (real
processes: a parent that spawns a child, killed with SIGKILL) and a stop reaches the
child's own children. The Prefect API server itself is exercised by
tests/test_reliability.py (a killed `touch2robot ingest`)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from touch2robot.local_server import spawn_owned, stop_group

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux only")

# a parent that starts `sleep` the way the command starts its servers, prints the
# child's pid, then waits to be killed
PARENT = textwrap.dedent(
    """
    import sys, time
    from touch2robot.local_server import spawn_owned
    child = spawn_owned(["sleep", "600"])
    print(child.pid, flush=True)
    time.sleep(600)
    """
)


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie waiting for its parent to reap it does not)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"


def wait_gone(pid: int, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    return not alive(pid)


def test_child_dies_when_its_parent_is_killed() -> None:
    parent = subprocess.Popen([sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True)
    child_pid = int(parent.stdout.readline())
    try:
        assert alive(child_pid)
        # a separate group: a group kill of the parent would not reach it, only the kernel does
        assert os.getpgid(child_pid) == child_pid != os.getpgid(parent.pid)
        parent.kill()
        parent.wait()
        assert wait_gone(child_pid), "the child outlived its SIGKILLed parent"
    finally:
        parent.kill()
        parent.wait()
        if alive(child_pid):
            os.kill(child_pid, signal.SIGKILL)


def test_stop_reaches_grandchildren_that_ignore_sigterm() -> None:
    # a shell that starts a grandchild ignoring SIGTERM (as MLflow's job workers outlive theirs)
    proc = spawn_owned(["sh", "-c", "trap '' TERM; sleep 600 & echo $!; wait"], stdout=subprocess.PIPE, text=True)
    grandchild = int(proc.stdout.readline())
    assert alive(grandchild)
    started = time.monotonic()
    stop_group(proc, grace_s=1.0)
    assert proc.returncode is not None
    assert wait_gone(grandchild), "the grandchild survived the stop"
    assert time.monotonic() - started < 10
