"""The process executor's liveness checks (the end-to-end kill tests are in test_crash)."""

from __future__ import annotations

import os
import subprocess
import sys
import time

from conformal_control.experiments.executors.process import process_alive


def test_process_alive_sees_exit_zombies_and_reuse() -> None:
    assert process_alive(os.getpid())
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    deadline = time.monotonic() + 30
    while process_alive(child.pid):  # exited but not reaped yet: a zombie is not alive
        assert time.monotonic() < deadline
        time.sleep(0.01)
    child.wait()
    assert not process_alive(child.pid)
    # the same PID with another start time (a reused PID) is not the process we watched
    assert not process_alive(os.getpid(), start="0")
