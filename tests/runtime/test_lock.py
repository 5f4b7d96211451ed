"""The run lock refuses a second live run and is taken over when its owner is gone."""

import json
import socket
import subprocess
import sys

import pytest

from pipeline.store.lock import RunLock, RunLockedError


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


def _contend(root: str, trials: int, barrier, results) -> None:
    """One racer: in each trial, all racers try to take the same fresh run's lock at the same moment."""
    from pathlib import Path

    for trial in range(trials):
        folder = Path(root) / f"trial-{trial}"
        barrier.wait()
        lock = RunLock(folder)
        try:
            lock.__enter__()
            held = 1
        except RunLockedError:
            held = 0
        except Exception:  # noqa: BLE001 - a racer that crashed on a half-written lock counts as a holder error
            held, lock = 100, None
        barrier.wait()  # every racer has tried while the winner still holds the lock
        if lock is not None and held:
            lock.__exit__(None, None, None)
        results.put((trial, held))
        barrier.wait()


def test_racing_processes_never_both_hold_the_lock(tmp_path):
    import multiprocessing

    trials, racers = 100, 8
    context = multiprocessing.get_context("spawn")  # no fork of a process that may run Ray threads
    barrier, results = context.Barrier(racers, timeout=60), context.Queue()
    processes = [context.Process(target=_contend, args=(str(tmp_path), trials, barrier, results)) for _ in range(racers)]
    for process in processes:
        process.start()
    holders = [0] * trials
    try:
        for _ in range(trials * racers):
            trial, held = results.get(timeout=60)
            holders[trial] += held
    finally:
        for process in processes:
            process.join(timeout=10)
            if process.is_alive():
                process.terminate()
    assert holders == [1] * trials, [(t, n) for t, n in enumerate(holders) if n != 1]
    assert not any((tmp_path / f"trial-{t}" / "_state" / "lock.json").exists() for t in range(trials))


def test_lock_appears_whole(tmp_path):
    with RunLock(tmp_path):
        record = json.loads((tmp_path / "_state" / "lock.json").read_text())
    assert record["pid"] > 0 and record["process_started"] > 0
    assert sorted(p.name for p in (tmp_path / "_state").iterdir()) == [".lock.guard"]  # no temporary left behind


def test_unreadable_recent_lock_is_not_taken(tmp_path):
    lock = tmp_path / "_state" / "lock.json"
    lock.parent.mkdir()
    lock.write_text("")  # a lock file being written by an older version: its owner may well be alive
    with pytest.raises(RunLockedError, match="unreadable"):
        with RunLock(tmp_path):
            pass
    assert lock.exists()
