"""Garbage collection of dead attempts (`mvpd gc`).

An attempt that died (SIGKILL, a lost node, a failed upload) leaves on object storage the objects it
uploaded under `_attempts/<stage>/<unit>/<attempt id>/`, and on local disk its staging folder
`_staging/<stage>/<unit>.<host>.<pid>/`. No marker names them, so no reader ever sees them; they only cost
storage. Garbage collection deletes them under the run lock: while it is held no driver runs this run, so
an attempt prefix that no marker names can never become committed. The markers' `keys` are the only
record of what is live (one listing of `_state/` and one batched fetch); `_attempts/` is listed once,
which is fine here (gc is not a hot path). Three extra precautions: a marker that cannot be fetched stops
the collection (its objects would look dead); an attempt of a process still alive on this host (a Ray
worker that outlived its driver) is left alone; and every batch of deletions is fenced like a commit (the
lock must still name this gc), so a gc that lost its lease during an outage stops before it deletes more.
"""

from __future__ import annotations

import json
import logging
import socket
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import psutil

import pipeline.store.links as links
from pipeline.store.names import ATTEMPTS, STAGING, STATE
from pipeline.store.remote import RunStore
from pipeline.store.run_folder import RunFolder

log = logging.getLogger(__name__)

# Objects deleted per request (S3 DeleteObjects takes at most 1000 keys).
DELETE_BATCH = 1000
# Called with (objects deleted so far, objects to delete) while deleting.
GarbageProgress = Callable[[int, int], None]


class GarbageCollectionError(RuntimeError):
    """The live set cannot be established (a marker could not be read); nothing was deleted."""


@dataclass
class GarbageReport:
    """What a collection found dead and (unless a dry run) deleted."""

    attempts: list[str] = field(default_factory=list)  # dead attempt prefixes on the store
    objects: int = 0
    bytes: int = 0
    staging: list[str] = field(default_factory=list)  # dead staging folders on local disk
    kept_alive: list[str] = field(default_factory=list)  # attempts of processes still alive on this host, left alone
    dry_run: bool = False


def collect_garbage(run: RunFolder, dry_run: bool = False, on_progress: GarbageProgress | None = None) -> GarbageReport:
    """Delete what dead attempts left behind in `run` (or only report it with `dry_run`), holding the run lock."""
    report = GarbageReport(dry_run=dry_run)
    run.check_links()
    with run.locked():
        if run.store is not None:
            _collect_store(run.store, report, on_progress, run.check_fence)
        _collect_staging(run.root, report, run.check_fence)
    return report


def live_attempts(store: RunStore) -> set[str]:
    """The attempt prefixes (`_attempts/<stage>/<unit>/<attempt id>`) some marker on the store names."""
    listed = sorted(k for k in store.list_objects(STATE) if k.endswith(".json"))
    texts = store.marker_texts(STATE)
    unread = [k for k in listed if k not in texts]
    if unread:
        raise GarbageCollectionError(f"{store.url}: {len(unread)} markers could not be read (first {unread[0]}); "
                                     "nothing was deleted; try again")
    live = set()
    for text in texts.values():
        try:
            keys = json.loads(text).get("keys")
        except (ValueError, AttributeError):
            continue  # not a marker's JSON (it names nothing a reader trusts)
        if isinstance(keys, dict):
            live.update(attempt_prefix(key) for key in keys.values() if isinstance(key, str))
    return live


def attempt_prefix(key: str) -> str:
    """`_attempts/<stage>/<unit>/<attempt id>` of an object key under `_attempts/`."""
    return "/".join(key.split("/")[:4])


def _collect_store(store: RunStore, report: GarbageReport, on_progress: GarbageProgress | None,
                   check_fence: Callable[[], None]) -> None:
    live = live_attempts(store)
    dead: dict[str, list[str]] = {}
    kept: set[str] = set()
    for key, size in store.list_objects(ATTEMPTS).items():
        prefix = attempt_prefix(key)
        if prefix in live or key.count("/") < 4:
            continue
        host, _, pid = prefix.rsplit("/", 1)[-1].rpartition(".")[0].rpartition(".")  # <host>.<pid>.<time_ns>
        if _alive_here(host, pid):
            kept.add(prefix)
            continue
        dead.setdefault(prefix, []).append(key)
        report.bytes += size
    doomed = sorted(k for keys in dead.values() for k in keys)
    report.attempts = sorted(dead)
    report.kept_alive.extend(sorted(kept))
    report.objects = len(doomed)
    if report.dry_run:
        return
    for start in range(0, len(doomed), DELETE_BATCH):
        check_fence()
        store.delete_objects(doomed[start:start + DELETE_BATCH])
        if on_progress is not None:
            on_progress(min(start + DELETE_BATCH, len(doomed)), len(doomed))
    log.info("%s: deleted %s objects (%s bytes) of %s dead attempts", store.url, len(doomed), report.bytes,
             len(report.attempts))


def _collect_staging(root: Path, report: GarbageReport, check_fence: Callable[[], None]) -> None:
    """Staging folders `_staging/<stage>/<unit>.<host>.<pid>` of attempts that are over: listed and deleted
    through no link (`pipeline.store.links`; the driver refused a run with links before, this is the guard)."""
    for stage, stage_is_folder in sorted(links.entries(root, STAGING)):
        if not stage_is_folder:
            continue
        for name, is_folder in sorted(links.entries(root, f"{STAGING}/{stage}")):
            if not is_folder:
                continue
            relative = f"{STAGING}/{stage}/{name}"
            owner, _, pid = name.rpartition(".")  # <unit>.<host>.<pid>
            if _alive_here(owner, pid):
                report.kept_alive.append(relative)
                continue
            report.staging.append(relative)
            if not report.dry_run:
                check_fence()
                links.remove(root, relative)


def _alive_here(owner: str, pid: str) -> bool:
    """True when `owner` (`<host>` or `<unit>.<host>`) is this host and process `pid` still runs here."""
    host = socket.gethostname()
    return (owner == host or owner.endswith(f".{host}")) and pid.isdigit() and psutil.pid_exists(int(pid))
