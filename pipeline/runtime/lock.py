"""The run lock: one `submit`/`rerun` per run folder at a time, never stuck after a crash.

`_state/lock.json` is created exclusively and holds host, pid and a heartbeat refreshed every
`HEARTBEAT_SECONDS`. A lock is stale (and taken over) when its process is gone on this host, or its
heartbeat is older than `STALE_SECONDS` (a run on another host that died).
"""

from __future__ import annotations

import json
import os
import socket
import threading
import time
from pathlib import Path

import psutil

HEARTBEAT_SECONDS = 20.0
STALE_SECONDS = 120.0


class RunLockedError(RuntimeError):
    """Another live run holds the run folder."""


class RunLock:
    """Context manager holding `_state/lock.json` for the duration of a run."""

    def __init__(self, run_root: Path):
        self.path = Path(run_root) / "_state" / "lock.json"
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def __enter__(self) -> "RunLock":
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if not self._try_create():
            holder = self._holder()
            if holder is not None and not _is_stale(holder):
                since = time.strftime("%H:%M:%S", time.localtime(holder.get("started", 0)))
                raise RunLockedError(
                    f"{self.path.parent.parent}: already being run by pid {holder.get('pid')} on "
                    f"{holder.get('host')} since {since}; wait for it to finish (`mvpd status`)"
                )
            self.path.unlink(missing_ok=True)  # stale: its owner is gone
            if not self._try_create():
                raise RunLockedError(f"{self.path}: another run took the lock just now; try again")
        self._thread = threading.Thread(target=self._beat, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        holder = self._holder()
        if holder is not None and holder.get("pid") == os.getpid() and holder.get("host") == socket.gethostname():
            self.path.unlink(missing_ok=True)

    def _record(self) -> dict:
        return {"host": socket.gethostname(), "pid": os.getpid(), "started": getattr(self, "_started", time.time()),
                "heartbeat": time.time()}

    def _try_create(self) -> bool:
        self._started = time.time()
        try:
            descriptor = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            return False
        with os.fdopen(descriptor, "w") as handle:
            json.dump(self._record(), handle)
        return True

    def _holder(self) -> dict | None:
        try:
            return json.loads(self.path.read_text())
        except (FileNotFoundError, ValueError):
            return None

    def _beat(self) -> None:
        while not self._stop.wait(HEARTBEAT_SECONDS):
            temporary = self.path.with_name(f".lock.{os.getpid()}.tmp")
            temporary.write_text(json.dumps(self._record()))
            os.replace(temporary, self.path)


def _is_stale(holder: dict) -> bool:
    if holder.get("host") == socket.gethostname():
        pid = int(holder.get("pid", -1))
        return not psutil.pid_exists(pid)
    return time.time() - float(holder.get("heartbeat", 0)) > STALE_SECONDS
