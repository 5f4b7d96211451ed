"""The run folder: resolved job, Parquet datasets, Zarr videos, markers, logs and the run lock.

Layout (see schemas/README.md):
    job.yaml                    resolved job + its hash
    <dataset>/part-<unit>.parquet
    videos/<embodiment>/<video_name>.zarr
    _state/<stage>/<unit>.json  markers: the only proof that a unit is done
    _staging/<stage>/<unit>/    where a running unit writes before its commit
    logs/<stage>/<unit>.log

The folder may also be an object-store URL (`s3://bucket/prefix`, `memory://...`): the run then lives on
the store and is read there, through its markers (`pipeline.runtime.object_store`, `store_markers`). A
local folder per URL (`MVPD_CACHE_DIR`) holds only what must be local: the job file, units' staging,
logs before upload and the lock's guard. It holds no output; readers given it read the store.
"""

from __future__ import annotations

import logging
import os
import shutil
import socket
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import pyarrow as pa
import yaml

from pipeline.config import ConfigError, Job, job_from_resolved
from pipeline.runtime.lock import Lease, check_fence, run_lock
from pipeline.runtime.failures import error_text
from pipeline.runtime import markers as marker_files
from pipeline.runtime.markers import (  # noqa: F401 - Marker and atomic_write_text are imported from here too
    DATASET_INDEX,
    STATE,
    Marker,
    atomic_write_text,
    code_version,
    is_plain_name,
    is_run_path,
    describe_files,
    marker_text,
)
from pipeline.runtime.object_store import (
    ATTEMPTS,
    REMOTE_FILE,
    RunStore,
    StoreError,
    attempt_id,
    cache_folder,
    local_path,
    remote_url,
    working_copy_url,
)
from pipeline.runtime.store_markers import indexed_datasets
from pipeline.runtime.tables import read_dataset

JOB_FILE = "job.yaml"
STAGING = "_staging"

log = logging.getLogger(__name__)


def run_root(run: "RunFolder | str | os.PathLike[str]") -> Path:
    """The local root of a RunFolder or a path; of an object-store URL, the local folder that stands for it
    (readers given it read the store).

    (A Path's own `.root` is "/", so paths are tested for first.)
    """
    if isinstance(run, (str, os.PathLike)):
        if remote_url(run) is not None:
            return RunFolder.open(run).root
        return Path(run).expanduser().resolve()
    return run.root

class RunFolderError(ValueError):
    """A path that is not a usable run folder; the message says why and what to do."""


class RunFolder:
    """A run folder on local disk, a shared file system, or an object store.

    `root` is always a local folder (the run itself, or the local folder standing for a remote run:
    staging, logs, the job file); `store` is the object-store side of a remote run (None on local disk)
    and `location` what a worker is handed.
    """

    def __init__(self, root: str | Path):
        url = remote_url(root)
        if url is None:
            self.root = local_path(root).expanduser().resolve()
            url = working_copy_url(self.root)
        else:
            self.root = cache_folder(url).resolve()
            self.root.mkdir(parents=True, exist_ok=True)
            if working_copy_url(self.root) != url:
                atomic_write_text(self.root / REMOTE_FILE, url)
        self.store = RunStore(url) if url else None
        self.location = self.store.url if self.store else str(self.root)
        self._indexed: set[str] = set()  # dataset index entries known to be on the store
        # The driver's run lock while it runs (`hold`), and the owner id its commits are fenced with (also
        # handed to the units it starts): a commit checks that the lock still names it (lock.check_fence).
        self.lease: Lease | None = None
        self.fence = ""

    @contextmanager
    def locked(self) -> Iterator[Lease]:
        """Hold the run lock (local, or on the store) while the block runs; its commits are fenced by it."""
        with run_lock(self) as lock:
            self.lease, self.fence = lock, lock.owner
            try:
                yield lock
            finally:
                self.lease, self.fence = None, ""

    def check_lease(self) -> None:
        """LeaseLostError when this driver's lease is lost (in memory, no I/O: before each unit starts)."""
        if self.lease is not None:
            self.lease.check()

    def check_fence(self) -> None:
        """LeaseLostError unless the run lock still names the driver this process commits for (a read of it)."""
        self.check_lease()
        if self.fence:
            check_fence(self, self.fence)

    # ------------------------------------------------------------------------------------ job
    @classmethod
    def prepare(cls, root: str | Path) -> "RunFolder":
        """Create the folder (or reopen a run); refuses a non-empty folder that is not a run."""
        run = cls(root)
        if run.store is not None:
            run._check_store()
            # A run's first key is its lock (`_state/`): a driver starting beside another finds the lock, not
            # a foreign folder, and is told who holds it.
            if not run.store.exists(JOB_FILE) and not run.store.exists(STATE) and run.store.exists(""):
                raise RunFolderError(f"{run.location}: exists, is not empty and has no {JOB_FILE}; "
                                     "choose an empty or new prefix")
            run._fetch_job()
            return run
        if run.root.exists() and not run.root.is_dir():
            raise RunFolderError(f"{run.root}: is a file, not a run folder; choose a folder path")
        is_run = (run.root / JOB_FILE).is_file() or (run.root / STATE).is_dir()
        if run.root.exists() and any(run.root.iterdir()) and not is_run:
            raise RunFolderError(f"{run.root}: exists, is not empty and has no {JOB_FILE}; choose an empty or new folder")
        try:
            run.root.mkdir(parents=True, exist_ok=True)
        except OSError as error:  # read-only file system, a parent that is a file, no permission
            raise RunFolderError(f"{run.root}: cannot create the run folder ({error.strerror}); "
                                 "choose a writable place (--run-dir)") from None
        return run

    @classmethod
    def create(cls, root: str | Path, job: Job) -> "RunFolder":
        """Create (or reopen) a run folder and save `job` in it."""
        run = cls.prepare(root)
        run.save_job(job)
        return run

    @classmethod
    def open(cls, root: str | Path) -> "RunFolder":
        run = cls(root)
        if run.store is not None:
            run._check_store()
            if not run.store.exists(JOB_FILE):
                raise RunFolderError(f"{run.location}: not a run folder (no {JOB_FILE}); give the URL `mvpd submit` wrote")
            run._fetch_job()
            return run
        if not (run.root / JOB_FILE).is_file():
            raise RunFolderError(f"{run.root}: not a run folder (no {JOB_FILE}); give the folder `mvpd submit` wrote")
        return run

    def save_job(self, job: Job) -> None:
        text = yaml.safe_dump({"job_hash": job.hash(), "job": job.resolved()}, sort_keys=False)
        atomic_write_text(self.root / JOB_FILE, text)
        if self.store is not None:
            self.store.put_text(JOB_FILE, text)

    def job(self) -> Job:
        try:
            data = yaml.safe_load((self.root / JOB_FILE).read_text())
            return job_from_resolved(data["job"])
        except yaml.YAMLError as error:
            raise ConfigError(f"{self.root / JOB_FILE}: not valid YAML ({' '.join(str(error).split())}); "
                              "resubmit the job") from None
        except (KeyError, TypeError, ValueError) as error:
            raise ConfigError(f"{self.root / JOB_FILE}: unreadable resolved job ({error}); resubmit the job") from None

    # -------------------------------------------------------------------------------- datasets
    def read(self, dataset: str) -> pa.Table:
        """All committed rows of a Parquet dataset of this run (marker-trusted parts only)."""
        return read_dataset(self.root, dataset)

    def datasets(self) -> list[str]:
        """Names of the Parquet datasets some marker has committed parts of."""
        if self.store is not None:
            return indexed_datasets(self.store)
        folder = self.root / STATE / marker_files.DATASET_INDEX
        return sorted(p.name for p in folder.iterdir() if p.is_dir() and any(p.iterdir())) if folder.is_dir() else []

    def video_store(self, embodiment: str, video_name: str) -> Path:
        """Where a unit stages (and, on local disk, commits) a video's Zarr store."""
        return self.root / "videos" / embodiment / f"{video_name}.zarr"

    def committed_location(self, marker: Marker, relative: str) -> str:
        """Where a file or Zarr store committed by `marker` is read: its local path, or its URL on the store."""
        if self.store is None:
            return str(self.root / relative)
        if relative in marker.keys:
            return self.store.url_of(marker.keys[relative])
        metadata = marker.keys.get(f"{relative}/zarr.json")  # a Zarr store: the folder of its metadata
        if metadata is None:
            raise KeyError(f"{marker.stage}/{marker.unit} committed no {relative}")
        return self.store.url_of(metadata.rsplit("/", 1)[0])

    def committed_part(self, stage: str, unit: str, dataset: str) -> str | None:
        """Where the part of `dataset` that `stage`/`unit` committed is read (see `committed_location`);
        None when the unit has no marker or wrote no such part."""
        relative = f"{dataset}/part-{unit}.parquet"
        marker = self.marker(stage, unit)
        return self.committed_location(marker, relative) if marker is not None and relative in marker.outputs else None

    # --------------------------------------------------------------------------------- markers
    def marker_path(self, stage: str, unit: str) -> Path:
        return marker_files.marker_path(self.root, stage, unit)

    def marker(self, stage: str, unit: str) -> Marker | None:
        """The unit's marker; None when missing, unreadable or without a manifest (the unit runs again)."""
        return marker_files.unit_marker(self.root, stage, unit)

    def markers(self, stage: str) -> dict[str, Marker]:
        return marker_files.stage_markers(self.root, stage)

    def write_marker(self, marker: Marker) -> None:
        """Write the marker, on the store last of all the unit's objects (the commit point)."""
        if self.store is None:
            marker_files.write_marker(self.root, marker)
            return
        for dataset in sorted({f.split("/")[0] for f in marker.outputs if f.endswith(".parquet")}):
            entry = f"{STATE}/{DATASET_INDEX}/{dataset}/{marker.stage}"
            if entry not in self._indexed:  # one HEAD per dataset per RunFolder, a PUT only the first time
                if not self.store.exists(entry):
                    self.store.put_text(entry, "")
                self._indexed.add(entry)
        self.store.put_text(self._marker_key(marker.stage, marker.unit), marker_text(marker))

    def drop_marker(self, stage: str, unit: str) -> None:
        if self.store is not None:
            self.store.remove([self._marker_key(stage, unit)])
        else:
            marker_files.drop_marker(self.root, stage, unit)

    # --------------------------------------------------------------------------------- staging
    def staging(self, stage: str, unit: str) -> Path:
        """A fresh, empty staging folder for one attempt of a unit."""
        path = self.root / STAGING / stage / f"{unit}.{socket.gethostname()}.{os.getpid()}"
        shutil.rmtree(path, ignore_errors=True)
        path.mkdir(parents=True)
        return path

    def commit_unit(self, stage: str, unit: str, staging: Path, config_hash: str, rows: dict[str, int],
                    seconds: float, attempt: int, finished_at: float, host: str,
                    info: dict[str, Any] | None = None, node: str = "") -> Marker:
        """The commit protocol of one unit attempt (schemas/README.md): outputs into place, marker last.

        The old marker goes first: a process that dies during the commit leaves a unit that is simply
        not done. The manifest (size and CRC-32C of every file) is taken from the staged files, which
        were just written and are read back from the page cache. The fence is checked before anything
        changes and again before the marker: a driver that lost the run lock commits nothing more.
        """
        self.check_fence()
        previous = self.marker(stage, unit)
        if previous is not None:
            self.drop_marker(stage, unit)
        outputs = sorted(_staged_outputs(staging))
        files = describe_files(staging, outputs)
        if self.store is not None:  # nothing is moved: the outputs stay under their attempt's keys
            keys = self._upload(stage, unit, staging, files)
            shutil.rmtree(staging, ignore_errors=True)
        else:
            keys = {}
            self.commit(staging, outputs, previous.outputs if previous else [])
        marker = Marker(stage, unit, config_hash, code_version(), outputs, rows, round(seconds, 3), attempt, host,
                        finished_at, info or {}, files, node=node, keys=keys)
        self.check_fence()
        self.write_marker(marker)
        if self.store is not None and previous is not None:  # the old attempt's objects, now named by nobody
            self.store.remove(sorted(set(previous.keys.values()) - set(keys.values())))
        return marker

    # ------------------------------------------------------------------------- object storage
    def _upload(self, stage: str, unit: str, staging: Path, files: list) -> dict[str, str]:
        """Upload the staged files under keys unique to this unit and attempt; logical path -> key.

        Nothing is renamed: a reader finds these keys only through the marker written after them, so an
        attempt that dies here (or whose upload fails) leaves objects no marker names.
        """
        assert self.store is not None
        base = f"{ATTEMPTS}/{stage}/{unit}/{attempt_id()}"
        keys = {entry.path: f"{base}/{entry.path}" for entry in files}
        self.store.put_files([(staging / path, key) for path, key in keys.items()])
        return keys

    def _check_store(self) -> None:
        assert self.store is not None
        try:
            self.store.check()
        except StoreError as error:
            raise RunFolderError(str(error)) from None

    @staticmethod
    def _marker_key(stage: str, unit: str) -> str:
        return f"{STATE}/{stage}/{unit}.json"

    def _fetch_job(self) -> None:
        """Keep the job file of a remote run in its local folder (one GET; the only file copied)."""
        assert self.store is not None
        job = self.store.read_text(JOB_FILE)
        if job is not None and job != _read(self.root / JOB_FILE):
            atomic_write_text(self.root / JOB_FILE, job)

    def upload_log(self, stage: str, unit: str) -> None:
        """Copy a unit's log to the store (best effort: a log is not an output)."""
        if self.store is None:
            return
        try:
            self.store.put_file(self.log_path(stage, unit), f"logs/{stage}/{unit}.log")
        except Exception as error:  # noqa: BLE001 - an outage raises botocore's or aiohttp's errors, no OSError
            log.warning("%s: log of %s/%s not uploaded (%s: %s)", self.location, stage, unit, type(error).__name__,
                        error_text(error))

    def commit(self, staging: Path, outputs: list[str], previous_outputs: list[str]) -> None:
        """Move the staged `outputs` (files or Zarr stores) into place, replacing earlier versions.

        Outputs of the unit's previous commit that this attempt did not produce are removed, so a
        rerun never leaves stale rows or videos behind.
        """
        for relative in outputs:
            target = self.inside(relative)
            target.parent.mkdir(parents=True, exist_ok=True)
            _replace(staging / relative, target)
        for relative in sorted(set(previous_outputs) - set(outputs)):
            _remove(self.inside(relative))
        shutil.rmtree(staging, ignore_errors=True)

    def inside(self, relative: str) -> Path:
        """The local path of an output of the run, after checking that it stays inside the run: a plain
        relative path (`is_run_path`) whose folders are no links leading elsewhere. Markers are checked when
        read; this is the last guard before anything is moved or deleted (RunFolderError otherwise)."""
        path = self.root / relative
        if not is_run_path(relative) or not path.parent.resolve().is_relative_to(self.root.resolve()):
            raise RunFolderError(f"{self.root}: refusing to write or delete {relative!r}, which is not a plain "
                                 "relative path inside the run")
        return path

    def log_path(self, stage: str, unit: str) -> Path:
        path = self.root / "logs" / stage / f"{unit}.log"
        path.parent.mkdir(parents=True, exist_ok=True)
        return path


def _read(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None


def _staged_outputs(staging: Path) -> list[str]:
    """Relative paths of staged outputs: files, and `*.zarr` folders taken whole."""
    outputs = []
    for dirpath, dirnames, filenames in os.walk(staging):
        base = Path(dirpath)
        for name in list(dirnames):
            if name.endswith(".zarr"):
                outputs.append(str((base / name).relative_to(staging)))
                dirnames.remove(name)
        outputs.extend(str((base / f).relative_to(staging)) for f in filenames)
    return outputs


def _replace(source: Path, target: Path) -> None:
    if source.is_dir():
        # A directory cannot be replaced atomically over a non-empty one: move the old one aside first.
        if target.exists():
            aside = target.with_name(f".{target.name}.old-{os.getpid()}-{time.monotonic_ns()}")
            os.replace(target, aside)
            os.replace(source, target)
            shutil.rmtree(aside, ignore_errors=True)
        else:
            os.replace(source, target)
    else:
        os.replace(source, target)


def _remove(path: Path) -> None:
    if path.is_dir():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)
