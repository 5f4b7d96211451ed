"""The run lock: one `submit`/`rerun` per run folder at a time, never stuck after a crash.

`_state/lock.json` holds host, pid, the process start time and a heartbeat refreshed every
`HEARTBEAT_SECONDS`. It appears with its content in one step: the record is written to a private
temporary file which is then hard-linked to the lock name, and `link` fails when the name exists, so
no process ever sees an empty or half-written lock. A lock is stale (and taken over) only when its
owner is provably gone: on this host, no process with its pid and start time; on another host, a
heartbeat older than `STALE_SECONDS`. Checking and taking over a stale lock happens under an
`flock` on `_state/.lock.guard`, so two processes cannot both remove it and both take the run.

A run folder on object storage (`s3://...`) keeps its lock on the store (`RemoteRunLock`), so drivers on
different machines exclude each other: the lock is created with a conditional PUT (`If-None-Match: *`,
exactly one of racing creators wins), the heartbeat and a takeover of a stale lock replace it only while
its ETag is the one read (`If-Match`), and release deletes it only while it is still ours. Nothing but
host, pid, times and an owner id is written: never a credential.
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
import socket
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Iterator

import psutil

if TYPE_CHECKING:
    from pipeline.runtime.object_store import RunStore
    from pipeline.runtime.run_folder import RunFolder

log = logging.getLogger(__name__)

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
                if not _is_stale(holder, _modified(self.path)):
                    raise RunLockedError(_held_message(self.path.parent.parent, self.path, holder))
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
        return _record(self._started)

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


LOCK_KEY = "_state/lock.json"


class RemoteRunLock:
    """Context manager holding `_state/lock.json` on the object store of a remote run (see the module doc).

    Every change of the lock object is conditional on what this process last saw of it, so a heartbeat
    never overwrites a new owner and two takers of one stale lock cannot both win: the second one's
    `If-Match` names an ETag the first one's write already replaced.
    """

    def __init__(self, store: "RunStore"):
        self.store = store
        self._owner = f"{socket.gethostname()}.{os.getpid()}.{time.time_ns()}"  # this holder, uniquely
        self._tag: str | None = None  # the ETag of the lock object as this process last wrote it
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._started = time.time()

    def __enter__(self) -> "RemoteRunLock":
        self._take()
        self._thread = threading.Thread(target=self._beat, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def _record(self) -> bytes:
        return json.dumps({**_record(self._started), "owner": self._owner}).encode("utf-8")

    def _take(self) -> None:
        """Create the lock, or take over a stale one; else RunLockedError (one line)."""
        for _ in range(3):  # the holder may release between our failed create and our read
            self._tag = self.store.create_object(LOCK_KEY, self._record())
            if self._tag is not None:
                return
            found = self.store.read_object(LOCK_KEY)
            if found is None:
                continue
            holder = _parse(found.data)
            if self._is_mine(holder):  # our create succeeded, its answer was lost and the retry was refused
                self._tag = found.tag
                return
            if not _is_stale(holder, found.modified):
                raise RunLockedError(_held_message(self.store.url, LOCK_KEY, holder))
            log.info("%s: taking over the stale lock of %s", self.store.url, holder)
            self._tag = self.store.replace_object(LOCK_KEY, self._record(), found.tag)
            if self._tag is not None:
                return
            # Changed since we read it: another driver took it over (the next round names it) or it was released.
        raise RunLockedError(f"{self.store.url}: the run lock keeps changing hands; try again")

    def release(self) -> None:
        """Stop the heartbeat and delete the lock if it is still ours (idempotent)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)
        if self._tag is not None:
            try:
                self.store.remove_object(LOCK_KEY, self._tag)
            except OSError as error:  # the run is over either way; a lock left behind goes stale
                log.warning("%s: could not remove the run lock (%s)", self.store.url, error)
            self._tag = None

    def _beat(self) -> None:
        while not self._stop.wait(HEARTBEAT_SECONDS):
            try:
                if not self._refresh():  # judged dead and taken over: never overwrite the new owner
                    log.error("%s: the run lock was taken over by another driver", self.store.url)
                    self._tag = None
                    return
            except OSError as error:  # a store hiccup: the next beat tries again, well before STALE_SECONDS
                log.warning("%s: heartbeat of the run lock failed (%s)", self.store.url, error)

    def _refresh(self) -> bool:
        """Rewrite the lock with a new heartbeat while it is ours; False when another driver holds it now."""
        tag = self.store.replace_object(LOCK_KEY, self._record(), self._tag or "")
        if tag is None:
            found = self.store.read_object(LOCK_KEY)
            if found is None or not self._is_mine(_parse(found.data)):
                return False
            tag = found.tag  # our earlier write landed, its answer was lost and the retry was refused
        self._tag = tag
        return True

    def _is_mine(self, holder: dict | None) -> bool:
        return holder is not None and holder.get("owner") == self._owner


def run_lock(run: "RunFolder") -> RunLock | RemoteRunLock:
    """The lock of a run folder: on its object store for a remote run, else the local lock file."""
    return RemoteRunLock(run.store) if run.store is not None else RunLock(run.root)


def _record(started: float) -> dict:
    """What a lock says about its holder: host, pid, process start, run start and heartbeat (nothing secret)."""
    return {"host": socket.gethostname(), "pid": os.getpid(), "process_started": _process_started(os.getpid()),
            "started": started, "heartbeat": time.time()}


def _parse(data: bytes) -> dict | None:
    try:
        holder = json.loads(data)
    except ValueError:
        return None
    return holder if isinstance(holder, dict) else None


def _held_message(run: object, path: object, holder: dict | None) -> str:
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


def _modified(path: Path) -> float | None:
    try:
        return path.stat().st_mtime
    except FileNotFoundError:
        return None


def _is_stale(holder: dict | None, modified: float | None) -> bool:
    """True only when the lock's owner is provably gone (`modified`: when the lock was last written, None if gone).

    Across machines this compares clocks: STALE_SECONDS (six missed heartbeats) leaves room for skew.
    """
    if holder is None:
        # Unreadable (written by an older version, or damaged): trust it until it is as old as a stopped heartbeat.
        return modified is None or time.time() - modified > STALE_SECONDS
    if holder.get("host") == socket.gethostname():
        pid = int(holder.get("pid", -1))
        if not psutil.pid_exists(pid):
            return True
        recorded, actual = holder.get("process_started"), _process_started(pid)
        # Same pid, another process (the pid was reused after the owner died).
        return recorded is not None and actual is not None and abs(float(recorded) - actual) > 1.0
    return time.time() - float(holder.get("heartbeat", 0)) > STALE_SECONDS
