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

The lock is a lease. The heartbeat survives any failure of the store or the disk (it retries with backoff);
a driver whose last successful heartbeat is older than `lease_seconds()` has lost its lease, since another
driver may take the lock once it is STALE_SECONDS old, so it stops committing: `RunFolder.commit_unit`
checks the fence (`check_fence`: the lock still names this driver's owner id with a fresh heartbeat)
before it changes anything and again before the marker, and the driver checks its lease before each unit
(`Lease.check`). A unit that finds the fence broken raises `LeaseLostError`, which stops the driver with
one line instead of being recorded as the unit's failure.
"""

from __future__ import annotations

import fcntl
import json
import logging
import math
import os
import socket
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Iterator

import psutil

from pipeline.errors import error_text
import pipeline.store.links as links
from pipeline.store.failures import RunStoppedError
from pipeline.store.names import STATE

if TYPE_CHECKING:
    from pipeline.store.remote import RunStore

log = logging.getLogger(__name__)

HEARTBEAT_SECONDS = 20.0
STALE_SECONDS = 120.0
_LAPSED = "no heartbeat reached the run lock for {:.0f} s"
# First wait before a failed heartbeat is tried again; doubled on each failure, at most HEARTBEAT_SECONDS.
RETRY_SECONDS = 1.0
LOCK_KEY = f"{STATE}/lock.json"
# A lock record is ~200 bytes; more is not read (a lock file of gigabytes is unreadable, not a memory bill).
_MAX_LOCK_BYTES = 64 * 1024


def lease_seconds() -> float:
    """How old the last heartbeat may be while this driver still commits: half of STALE_SECONDS, so that a
    driver stops well before another one may take its lock over (room for clock skew and a slow commit)."""
    return STALE_SECONDS / 2


class RunLockedError(RuntimeError):
    """Another live run holds the run folder."""


class LeaseLostError(RunStoppedError):
    """This driver's lease on the run lapsed or was taken over: it must not commit anything more. The driver
    stopped, as after an outage (exit 1), its input was fine (not a RunLockedError, exit 2)."""


class RunFolderNotWritableError(RunLockedError):
    """The lock cannot be created: the run folder is on a read-only file system or not writable."""


class Lease:
    """What both locks share: the owner id, the heartbeat thread and the lease it keeps (module doc).

    A subclass writes the heartbeat in `_refresh` (True while the lock is still ours) and names the run in
    `where`; every exception of a heartbeat is survived and tried again with backoff.
    """

    where: str

    def __init__(self) -> None:
        self.owner = f"{socket.gethostname()}.{os.getpid()}.{time.time_ns()}"  # this holder, uniquely
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._started = time.time()
        self._renewed = time.monotonic()  # when a heartbeat last reached the lock
        self.lost: str | None = None  # why the lease is lost (None while it holds)

    def _refresh(self) -> bool:
        raise NotImplementedError

    def _start_heartbeat(self) -> None:
        self._renewed = time.monotonic()
        self._thread = threading.Thread(target=self._beat, daemon=True, name="mvpd-lock-heartbeat")
        self._thread.start()

    def _stop_heartbeat(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)

    def _beat(self) -> None:
        """Renew the lock every HEARTBEAT_SECONDS; after a failure, again after 1, 2, 4 ... s (at most
        HEARTBEAT_SECONDS) until it works, the lease lapses, or another driver is found holding the lock."""
        failures = 0
        while not self._stop.wait(_next_beat(failures)):
            try:
                if not self._refresh():  # judged dead and taken over: never overwrite the new owner
                    self.lost = "another driver took the run lock over"
                    log.error("%s: %s", self.where, self.lost)
                    return
                self._renewed, failures = time.monotonic(), 0
            except Exception as error:  # noqa: BLE001 - a store raises its own types (botocore's, aiohttp's)
                failures += 1
                log.warning("%s: heartbeat of the run lock failed (%s: %s); trying again", self.where,
                            type(error).__name__, error_text(error))
                if self._lapsed():
                    self.lost = _LAPSED.format(lease_seconds())
                    log.error("%s: %s", self.where, self.lost)
                    return

    def _lapsed(self) -> bool:
        return time.monotonic() - self._renewed > lease_seconds()

    def _is_mine(self, holder: dict | None) -> bool:
        return holder is not None and holder.get("owner") == self.owner

    def check(self) -> None:
        """Raise LeaseLostError (one line) when this driver must stop committing (the driver's own fence)."""
        if self.lost is None and self._lapsed():
            self.lost = _LAPSED.format(lease_seconds())
        if self.lost is not None:
            raise LeaseLostError(lease_lost_message(self.where, self.lost))


def _next_beat(failures: int) -> float:
    """Seconds to the next heartbeat: HEARTBEAT_SECONDS, or a backoff after `failures` failed ones in a row."""
    return HEARTBEAT_SECONDS if not failures else min(HEARTBEAT_SECONDS, RETRY_SECONDS * 2 ** (failures - 1))


def lease_lost_message(where: object, why: str) -> str:
    return (f"{where}: stopped: {why}, so another driver may be running this run; nothing more was committed "
            "by this one (`mvpd status` shows what is done; rerun when no other driver runs it)")


class RunLock(Lease):
    """Context manager holding `_state/lock.json` for the duration of a run."""

    def __init__(self, run_root: Path):
        super().__init__()
        self.root = Path(run_root)
        self.path = self.root / LOCK_KEY
        self.where = str(self.root)
        self._guard = self.path.with_name(".lock.guard")

    def __enter__(self) -> "RunLock":
        try:
            self.root.mkdir(parents=True, exist_ok=True)  # the folder named (links above it are the user's)
            links.make_folder(self.root, STATE)  # `_state` a link: RunLinkError, nothing written through it
            self._take()
        except OSError as error:
            raise RunFolderNotWritableError(f"{self.path.parent.parent}: cannot create the run lock "
                                            f"({error.strerror}); choose a writable run folder") from None
        self._start_heartbeat()
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
        """Stop the heartbeat and remove the lock if this process still holds it (idempotent; a failing disk
        leaves the lock behind with a warning: its owner is gone, so it is stale for the next driver)."""
        self._stop_heartbeat()
        try:
            with self._guarded():
                if self._is_mine(self._holder()):
                    self.path.unlink(missing_ok=True)
        except OSError as error:
            log.warning("%s: could not remove the run lock (%s)", self.where, error)

    @contextmanager
    def _guarded(self) -> Iterator[None]:
        """Hold an exclusive flock on the guard file (taken only for the few file operations, never the run)."""
        descriptor = os.open(self._guard, os.O_CREAT | os.O_RDWR | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX)
            yield
        finally:
            os.close(descriptor)  # closing releases the flock

    def _record(self) -> dict:
        return {**_record(self._started), "owner": self.owner}

    def _try_create(self) -> bool:
        """Publish the lock with its whole content in one step; False when a lock already exists."""
        temporary = self.path.with_name(f".lock.{socket.gethostname()}.{os.getpid()}.tmp")
        _write_new(temporary, json.dumps(self._record()))
        try:
            os.link(temporary, self.path)  # fails, never replaces, when the name exists
        except FileExistsError:
            return False
        finally:
            temporary.unlink(missing_ok=True)
        return True

    def _holder(self) -> dict | None:
        return local_holder(self.path)

    def _refresh(self) -> bool:
        with self._guarded():
            if not self._is_mine(self._holder()):
                return False  # taken over (judged dead from another host): never overwrite the new owner
            temporary = self.path.with_name(f".lock.{os.getpid()}.beat.tmp")
            _write_new(temporary, json.dumps(self._record()))
            os.replace(temporary, self.path)
            return True


def _write_new(path: Path, text: str) -> None:
    """Write a private temporary file of the lock; a link at its name is replaced, never followed."""
    path.unlink(missing_ok=True)
    with open(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644), "w") as out:
        out.write(text)


def local_holder(path: Path) -> dict | None:
    """The record of a local lock file; None when there is none or it is unreadable (a folder, a link, bytes
    that are no JSON object: any bytes give a record or None)."""
    try:
        with open(os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC), "rb") as handle:
            return parse_holder(handle.read(_MAX_LOCK_BYTES))
    except OSError:
        return None


class RemoteRunLock(Lease):
    """Context manager holding `_state/lock.json` on the object store of a remote run (see the module doc).

    Every change of the lock object is conditional on what this process last saw of it, so a heartbeat
    never overwrites a new owner and two takers of one stale lock cannot both win: the second one's
    `If-Match` names an ETag the first one's write already replaced.
    """

    def __init__(self, store: "RunStore"):
        super().__init__()
        self.store = store
        self.where = store.url
        self._tag: str | None = None  # the ETag of the lock object as this process last wrote it

    def __enter__(self) -> "RemoteRunLock":
        self._take()
        self._start_heartbeat()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def _record(self) -> bytes:
        return json.dumps({**_record(self._started), "owner": self.owner}).encode("utf-8")

    def _take(self) -> None:
        """Create the lock, or take over a stale one; else RunLockedError (one line)."""
        for _ in range(3):  # the holder may release between our failed create and our read
            self._tag = self.store.create_object(LOCK_KEY, self._record())
            if self._tag is not None:
                return
            found = self.store.read_object(LOCK_KEY)
            if found is None:
                continue
            holder = parse_holder(found.data)
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
        """Stop the heartbeat and delete the lock if it is still ours (idempotent). Any failure of the store
        is survived with a warning: the run is over either way, and a lock left behind goes stale."""
        self._stop_heartbeat()
        if self._tag is not None:
            try:
                self.store.remove_object(LOCK_KEY, self._tag)
            except Exception as error:  # noqa: BLE001 - botocore's and aiohttp's errors are no OSError
                log.warning("%s: could not remove the run lock (%s: %s)", self.store.url, type(error).__name__,
                            error_text(error))
            self._tag = None

    def _refresh(self) -> bool:
        """Rewrite the lock with a new heartbeat while it is ours; False when another driver holds it now."""
        tag = self.store.replace_object(LOCK_KEY, self._record(), self._tag or "")
        if tag is None:
            found = self.store.read_object(LOCK_KEY)
            if found is None or not self._is_mine(parse_holder(found.data)):
                self._tag = None
                return False
            tag = found.tag  # our earlier write landed, its answer was lost and the retry was refused
        self._tag = tag
        return True


def check_fence(holder: dict | None, owner: str, where: str) -> None:
    """Raise LeaseLostError unless the run's lock (`holder`, as just read) still names `owner` with a heartbeat
    younger than the lease.

    Checked before a commit changes anything and before its marker (in Ray workers too, which see only the
    lock, not the driver): one small read of the lock file, or one GET of the lock object.
    """
    if holder is None or holder.get("owner") != owner:
        who = "nobody" if holder is None else f"pid {holder.get('pid')} on {holder.get('host')}"
        raise LeaseLostError(lease_lost_message(where, f"the run lock is now held by {who}"))
    age = time.time() - float(holder.get("heartbeat", 0))
    if age > lease_seconds():
        raise LeaseLostError(lease_lost_message(where, f"the run lock's last heartbeat is {age:.0f} s old"))


def parse_holder(data: bytes) -> dict | None:
    """The record of a lock object's bytes; None when unreadable."""
    try:
        holder = json.loads(data)
    except (ValueError, RecursionError):  # not JSON, or `[` nested too deep for the parser
        return None
    return holder if isinstance(holder, dict) and _well_typed(holder) else None


def _well_typed(holder: dict) -> bool:
    """True when the record's fields, where present, have the types a lock of ours writes (a forged or damaged
    lock is unreadable, judged by its age, rather than crashing the reader)."""
    def number(key: str, optional: bool = False) -> bool:
        value = holder.get(key)
        return (value is None and (optional or key not in holder)) or (
            isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value))

    pid = holder.get("pid", 1)
    return (isinstance(holder.get("host", ""), str) and isinstance(holder.get("owner", ""), str)
            and isinstance(pid, int) and not isinstance(pid, bool) and 0 < pid < 2**31
            and number("started") and number("heartbeat") and number("process_started", optional=True)
            and abs(holder.get("started") or 0) < 1e11)


def _record(started: float) -> dict:
    """What a lock says about its holder: host, pid, process start, run start and heartbeat (nothing secret)."""
    return {"host": socket.gethostname(), "pid": os.getpid(), "process_started": _process_started(os.getpid()),
            "started": started, "heartbeat": time.time()}


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
        try:
            pid = int(holder.get("pid", -1))
        except (TypeError, ValueError):  # not a pid: written by no driver of ours; judged by its age
            return modified is None or time.time() - modified > STALE_SECONDS
        if not psutil.pid_exists(pid):
            return True
        recorded, actual = holder.get("process_started"), _process_started(pid)
        # Same pid, another process (the pid was reused after the owner died).
        return recorded is not None and actual is not None and abs(float(recorded) - actual) > 1.0
    try:
        return time.time() - float(holder.get("heartbeat", 0)) > STALE_SECONDS
    except (TypeError, ValueError):
        return modified is None or time.time() - modified > STALE_SECONDS
