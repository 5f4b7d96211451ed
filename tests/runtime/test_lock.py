"""The run lock refuses a second live run and is taken over when its owner is gone."""

import json
import socket
import subprocess
import sys

import pytest

from pipeline.runtime.lock import RunLock, RunLockedError


def test_second_lock_on_a_live_run_is_refused(tmp_path):
    with RunLock(tmp_path):
        with pytest.raises(RunLockedError, match="already being run by pid"):
            with RunLock(tmp_path):
                pass
    assert not (tmp_path / "_state" / "lock.json").exists()  # released on exit


def test_lock_of_a_dead_process_is_taken_over(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    lock = tmp_path / "_state" / "lock.json"
    lock.parent.mkdir()
    lock.write_text(json.dumps({"host": socket.gethostname(), "pid": int(dead.stdout), "started": 0, "heartbeat": 0}))
    with RunLock(tmp_path):
        assert json.loads(lock.read_text())["pid"] != int(dead.stdout)


def test_lock_of_another_host_is_stale_only_after_its_heartbeat_stops(tmp_path):
    import time

    lock = tmp_path / "_state" / "lock.json"
    lock.parent.mkdir()
    lock.write_text(json.dumps({"host": "elsewhere", "pid": 1, "started": 0, "heartbeat": time.time()}))
    with pytest.raises(RunLockedError):
        with RunLock(tmp_path):
            pass
    lock.write_text(json.dumps({"host": "elsewhere", "pid": 1, "started": 0, "heartbeat": time.time() - 3600}))
    with RunLock(tmp_path):
        pass
