"""The run lock: one `submit`/`rerun` per run folder at a time, never stuck after a crash.

`_state/lock.json` holds host, pid, the process start time and a heartbeat refreshed every
`HEARTBEAT_SECONDS`. It appears with its content in one step: the record is written to a private
temporary file which is then hard-linked to the lock name, and `link` fails when the name exists, so
no process ever sees an empty or half-written lock. A lock is stale (and taken over) only when its
owner is provably gone: on this host, no process with its pid and start time; on another host, a
heartbeat older than `STALE_SECONDS`. Checking and taking over a stale lock happens under an
`flock` on `_state/.lock.guard`, so two processes cannot both remove it and both take the run.
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import psutil

HEARTBEAT_SECONDS = 20.0
STALE_SECONDS = 120.0


class RunLockedError(RuntimeError):
    """Another live run holds the run folder."""


class RunFolderNotWritableError(RunLockedError):
    """The lock cannot be created: the run folder is on a read-only file system or not writable."""


class RunLock:
    """Context manager holding `_state/lock.json` for the duration of a run."""

    def __init__(self, run_root: Path):
        self.path = Path(run_root) / "_state" / "lock.json"
        self._guard = self.path.with_name(".lock.guard")
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._started = time.time()

    def __enter__(self) -> "RunLock":
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._take()
        except OSError as error:
            raise RunFolderNotWritableError(f"{self.path.parent.parent}: cannot create the run lock "
                                            f"({error.strerror}); choose a writable run folder") from None
        self._thread = threading.Thread(target=self._beat, daemon=True)
        self._thread.start()
        return self

    def _take(self) -> None:
        """Create the lock, or take it over when its owner is provably gone; else RunLockedError."""
        with self._guarded():
            if not self._try_create():
                holder = self._holder()
                if not _is_stale(holder, self.path):
                    raise RunLockedError(_held_message(self.path, holder))
                self.path.unlink(missing_ok=True)  # its owner is gone; the guard keeps others out meanwhile
                if not self._try_create():
                    raise RunLockedError(f"{self.path}: another run took the lock just now; try again")

    def __exit__(self, *exc: object) -> None:
        self.release()

    def release(self) -> None:
        """Stop the heartbeat and remove the lock if this process still holds it (idempotent)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)
        with self._guarded():
            if self._is_mine(self._holder()):
                self.path.unlink(missing_ok=True)

    @contextmanager
    def _guarded(self) -> Iterator[None]:
        """Hold an exclusive flock on the guard file (taken only for the few file operations, never the run)."""
        descriptor = os.open(self._guard, os.O_CREAT | os.O_RDWR, 0o644)
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX)
            yield
        finally:
            os.close(descriptor)  # closing releases the flock

    def _record(self) -> dict:
        return {"host": socket.gethostname(), "pid": os.getpid(), "process_started": _process_started(os.getpid()),
                "started": self._started, "heartbeat": time.time()}

    def _is_mine(self, holder: dict | None) -> bool:
        return holder is not None and holder.get("pid") == os.getpid() and holder.get("host") == socket.gethostname()

    def _try_create(self) -> bool:
        """Publish the lock with its whole content in one step; False when a lock already exists."""
        temporary = self.path.with_name(f".lock.{socket.gethostname()}.{os.getpid()}.tmp")
        temporary.write_text(json.dumps(self._record()))
        try:
            os.link(temporary, self.path)  # fails, never replaces, when the name exists
        except FileExistsError:
            return False
        finally:
            temporary.unlink(missing_ok=True)
        return True

    def _holder(self) -> dict | None:
        try:
            data = json.loads(self.path.read_text())
        except (FileNotFoundError, ValueError):
            return None
        return data if isinstance(data, dict) else None

    def _beat(self) -> None:
        while not self._stop.wait(HEARTBEAT_SECONDS):
            with self._guarded():
                if not self._is_mine(self._holder()):
                    return  # taken over (judged dead from another host): never overwrite the new owner
                temporary = self.path.with_name(f".lock.{os.getpid()}.beat.tmp")
                temporary.write_text(json.dumps(self._record()))
                os.replace(temporary, self.path)


def _held_message(path: Path, holder: dict | None) -> str:
    run = path.parent.parent
    if holder is None:
        return f"{run}: {path} is held but unreadable; if no run is going on, delete it and try again"
    since = time.strftime("%H:%M:%S", time.localtime(holder.get("started", 0)))
    return (f"{run}: already being run by pid {holder.get('pid')} on {holder.get('host')} since {since}; "
            "wait for it to finish (`mvpd status`)")


def _process_started(pid: int) -> float | None:
    try:
        return psutil.Process(pid).create_time()
    except (psutil.NoSuchProcess, psutil.AccessDenied):
        return None


def _is_stale(holder: dict | None, path: Path) -> bool:
    """True only when the lock's owner is provably gone."""
    if holder is None:
        # Unreadable (written by an older version, or damaged): trust it until it is as old as a stopped heartbeat.
        try:
            return time.time() - path.stat().st_mtime > STALE_SECONDS
        except FileNotFoundError:
            return True
    if holder.get("host") == socket.gethostname():
        pid = int(holder.get("pid", -1))
        if not psutil.pid_exists(pid):
            return True
        recorded, actual = holder.get("process_started"), _process_started(pid)
        # Same pid, another process (the pid was reused after the owner died).
        return recorded is not None and actual is not None and abs(float(recorded) - actual) > 1.0
    return time.time() - float(holder.get("heartbeat", 0)) > STALE_SECONDS
