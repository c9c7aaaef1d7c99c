"""The sweep folder's lock: exclusive, names its owner, released however its holder ends."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from conformal_control.experiments import SweepLock, SweepLockedError


def test_a_second_holder_is_refused_with_the_owner_named(tmp_path: Path) -> None:
    with SweepLock(tmp_path) as lock:
        owner = json.loads((tmp_path / ".lock").read_text())
        assert owner["pid"] == os.getpid() and owner["host"] == socket.gethostname()
        with pytest.raises(SweepLockedError) as info:
            SweepLock(tmp_path).acquire()  # flock: another open file conflicts, same process too
        msg = str(info.value)
        assert f"another sweep (PID {os.getpid()} on {socket.gethostname()})" in msg
        assert "\n" not in msg and lock.locked
    assert (tmp_path / ".lock").read_text() == ""  # released: no owner
    with SweepLock(tmp_path):  # free again
        pass


def test_a_killed_holder_leaves_no_stale_lock(tmp_path: Path) -> None:
    code = (
        "import sys, time\n"
        "from conformal_control.experiments import SweepLock\n"
        f"SweepLock({str(tmp_path)!r}).acquire()\n"
        "print('locked', flush=True)\n"
        "time.sleep(600)\n"
    )
    holder = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(SweepLockedError, match=f"PID {holder.pid} "):
            SweepLock(tmp_path).acquire()
        holder.kill()
        holder.wait()
        assert json.loads((tmp_path / ".lock").read_text())["pid"] == holder.pid  # stale text
        with SweepLock(tmp_path):  # but the OS released the lock with the process
            assert json.loads((tmp_path / ".lock").read_text())["pid"] == os.getpid()
    finally:
        holder.kill()
        holder.wait()
        holder.stdout.close()
