"""The run folder: one object for everything about a run's bytes, opened once from a path or a URL.

`RunFolder.open` (an existing run), `prepare` (a new or existing one) and `create` (and save the job)
resolve the location once: a local directory, or an object-store URL (`s3://bucket/prefix`,
`memory://...`) whose run lives on the store and is read there. Which of the two it is is decided here and
nowhere else (`backends.LocalFiles` or `backends.StoreFiles`); every reader and writer below the command
line is handed the opened object. A process that is handed a run by another one (a Ray worker) gets its
`RunAddress` and opens it once.

A local folder per URL (`MVPD_CACHE_DIR`) holds only what must be local for a remote run: the job file,
units' staging, logs before upload and the lock's guard. It holds no output.
"""

from __future__ import annotations

import logging
import os
import socket
import time
from contextlib import contextmanager
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import IO, Any, Iterator

import pyarrow as pa
import yaml

from pipeline.config import ConfigError, Job, job_from_resolved, load_yaml
from pipeline.errors import error_text
import pipeline.store.links as links
from pipeline.store.backends import LocalFiles, RunFiles, RunFolderError, StoreFiles
from pipeline.store.links import FolderCheck
from pipeline.store.datasets import CheckedStages, TrustedPart, damage_line
from pipeline.store.lock import Lease, check_fence
from pipeline.store.marker_index import load_markers, write_index
from pipeline.store.markers import Damage, Marker, code_version, describe_files
from pipeline.store.names import JOB_FILE, REMOTE_FILE, STAGING, atomic_write_text
from pipeline.store.remote import RunStore, cache_folder, local_path, remote_url, working_copy_url
from pipeline.store.tables import spec, write_part

__all__ = ["RunAddress", "RunFolder", "RunFolderError", "as_run"]

log = logging.getLogger(__name__)


class RunFolder:
    """A run folder on local disk, a shared file system, or an object store.

    `root` is always a local folder (the run itself, or the local folder standing for a remote run:
    staging, logs, the job file); `store` is the object-store side of a remote run (None on local disk)
    and `location` what a user is shown and a worker is handed.
    """

    def __init__(self, location: str | os.PathLike[str]):
        url = remote_url(location)
        if url is None:
            self.root = local_path(location).expanduser().resolve()
            url = working_copy_url(self.root)  # a remote run's local folder stands for its store
        else:
            self.root = cache_folder(url).resolve()
            self.root.mkdir(parents=True, exist_ok=True)
            if working_copy_url(self.root) != url:
                atomic_write_text(self.root / REMOTE_FILE, url)
        self.store = RunStore(url) if url else None
        self.files: RunFiles = StoreFiles(self.store, self.root) if self.store else LocalFiles(self.root)
        self.location = self.files.location
        # The driver's run lock while it runs (`locked`), and the owner id its commits are fenced with (also
        # handed to the units it starts): a commit checks that the lock still names it (lock.check_fence).
        self.lease: Lease | None = None
        self.fence = ""
        # Stage -> names of its marker files that are no valid marker, as `markers` last found them (`status`
        # names them: the unit is not done and its next commit replaces the file).
        self.unreadable_markers: dict[str, list[str]] = {}

    # ------------------------------------------------------------------------------ opening
    @classmethod
    def open(cls, location: str | os.PathLike[str]) -> "RunFolder":
        """An existing run (RunFolderError when there is none at `location`)."""
        run = cls(location)
        run.files.check_run()
        return run

    @classmethod
    def prepare(cls, location: str | os.PathLike[str]) -> "RunFolder":
        """Create the folder (or reopen a run); refuses a non-empty folder that is not a run."""
        return cls(location).prepared()

    def prepared(self) -> "RunFolder":
        """This run folder, created when new (or a run found in it); refuses a non-empty folder that is not a
        run. For a command that checks its inputs before it creates anything."""
        self.files.prepare()
        return self

    @classmethod
    def create(cls, location: str | os.PathLike[str], job: Job) -> "RunFolder":
        """Create (or reopen) a run folder and save `job` in it."""
        run = cls.prepare(location)
        run.save_job(job)
        return run

    def address(self) -> "RunAddress":
        """What another process (a Ray worker) is handed to open this run: no store client, no credential."""
        return RunAddress(self.location, self.fence)

    def __repr__(self) -> str:
        return f"RunFolder({self.location!r})"

    # ---------------------------------------------------------------------------------- job
    def save_job(self, job: Job) -> None:
        self.files.save_job(yaml.safe_dump({"job_hash": job.hash(), "job": job.resolved()}, sort_keys=False))

    def job_text(self) -> str:
        """The run's job file as written by `save_job` (read without following a link on local disk)."""
        return self.files.read_job() if isinstance(self.files, LocalFiles) else (self.root / JOB_FILE).read_text()

    def job(self) -> Job:
        try:
            return job_from_resolved(self._job_document()["job"])
        except yaml.YAMLError as error:
            raise ConfigError(f"{self.root / JOB_FILE}: not valid YAML ({' '.join(str(error).split())}); "
                              "resubmit the job") from None
        except (OSError, UnicodeDecodeError, RecursionError) as error:  # a folder, bad bytes (a link: RunLinkError)
            raise ConfigError(f"{self.root / JOB_FILE}: cannot be read ({error_text(error)}); resubmit the job") from None
        except (KeyError, TypeError, ValueError) as error:
            raise ConfigError(f"{self.root / JOB_FILE}: unreadable resolved job ({error}); resubmit the job") from None

    def job_hash(self) -> str:
        """The job hash `save_job` recorded beside the resolved job."""
        return str(self._job_document().get("job_hash", ""))

    def _job_document(self) -> dict:
        document = load_yaml(self.job_text())
        if not isinstance(document, dict):
            raise TypeError("the job file is not a mapping")
        return document

    # --------------------------------------------------------------------------------- lock
    @contextmanager
    def locked(self) -> Iterator[Lease]:
        """Hold the run lock (local, or on the store) while the block runs; its commits are fenced by it."""
        with self.files.lock() as lock:
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
            check_fence(self.files.lock_holder(), self.fence, self.location)

    # ------------------------------------------------------------------------------ markers
    def marker(self, stage: str, unit: str) -> Marker | None:
        """The unit's marker; None when missing, unreadable or without a manifest (the unit runs again)."""
        return self.files.read_marker(stage, unit)

    def markers(self, stage: str) -> dict[str, Marker]:
        """Every valid marker of one stage, by unit id (through the stage's marker index, a cache checked
        against one listing of the folder: `pipeline.store.marker_index`)."""
        unreadable: list[str] = []
        found = load_markers(self.files.marker_folder(stage), unreadable=unreadable)
        self.unreadable_markers[stage] = unreadable
        return found

    def write_marker(self, marker: Marker) -> None:
        """Write a marker as a commit does, last (tools and fixtures that mark units done without outputs)."""
        self.files.write_marker(marker)

    def drop_marker(self, stage: str, unit: str) -> None:
        """Take a unit's marker away: the unit is not done (its outputs stay until it commits again)."""
        self.files.drop_marker(stage, unit)

    def index_markers(self, stage: str) -> int:
        """Bring the stage's marker index up to date (the driver, after a stage run); how many it holds."""
        return write_index(self.files.marker_folder(stage))

    def marked_stages(self) -> list[str]:
        """Stages (including pseudo-stages such as the status table's) that have a marker folder."""
        return self.files.marked_stages()

    def stages_writing(self, dataset: str) -> list[str]:
        """Stages with committed parts of `dataset` (from the dataset index, no scan of the data folders)."""
        return self.files.stages_writing(dataset)

    def datasets(self) -> list[str]:
        """Names of the Parquet datasets some marker has committed parts of."""
        return self.files.datasets()

    # ------------------------------------------------------------------------------- damage
    def check_files(self, marker: Marker, verify: bool = False, recorded: bool = True) -> list[Damage]:
        """Problems of a marker's files: missing or resized (a stat each; objects on a store only with
        `verify`); with `verify`, also a checksum mismatch. `recorded` adds the damage an earlier verify or
        reader noted for this marker (`record_damage`)."""
        found = self.files.check(marker, verify)
        return (found + self.files.recorded_damage([marker])[0]) if recorded else found

    def damage(self, markers: dict[str, Marker]) -> dict[str, list[Damage]]:
        """Unit id -> problems, for the units of `markers` whose committed files are not as their marker says.

        One thread: over 2 M files on this 2-core machine, two threads of os.stat took 1.3-2.6x as long as
        one (measured on the 18,000 x 120-file run of benchmarks/bench_scaling.py), so the loop stays plain.
        """
        units, found = list(markers), self.files.recorded_damage(list(markers.values()))
        check = self.files.check
        if isinstance(self.files, LocalFiles):  # each output's folders lstat'ed once in this pass, not per file
            check = partial(check, folders=FolderCheck(self.root), deep=False)
        problems = {unit: check(markers[unit], False) + noted for unit, noted in zip(units, found)}
        return {unit: damage for unit, damage in problems.items() if damage}

    def record_damage(self, stage: str, damaged: list[tuple[Marker, list[Damage]]] = (),
                      cleared: list[str] = ()) -> None:
        """Remember damage found by reading (a checksum, an unreadable part) so that `rerun` repairs those
        units, and forget the notes of units found intact. A note names the marker it judged (`finished_at`):
        a unit committed again since is not affected."""
        self.files.update_damage(stage, damaged, cleared)

    # ----------------------------------------------------------------------- committed files
    def committed_location(self, marker: Marker, relative: str) -> str:
        """Where a file or Zarr store committed by `marker` is read: its local path, or its URL on the store."""
        return str(self.files.path_of(marker, relative))

    def committed_part(self, stage: str, unit: str, dataset: str) -> str | None:
        """Where the part of `dataset` that `stage`/`unit` committed is read (see `committed_location`);
        None when the unit has no marker or wrote no such part."""
        relative = f"{dataset}/part-{unit}.parquet"
        marker = self.marker(stage, unit)
        return self.committed_location(marker, relative) if marker is not None and relative in marker.outputs else None

    def trusted_parts(self, dataset: str,
                      checked: CheckedStages | None = None) -> tuple[list[TrustedPart], list[Damage]]:
        """Part files of `dataset` named by markers of undamaged units, sorted, and the damage that left the
        others out (`checked` shares each stage's markers and damage between datasets)."""
        checked = {} if checked is None else checked
        parts, damaged = [], []
        prefix = f"{dataset}/"
        for stage in self.stages_writing(dataset):
            if stage not in checked:
                markers = self.markers(stage)
                # Any bad file of the unit withholds all its rows: a `videos` row whose Zarr lost a shard would
                # otherwise send readers to zeros.
                checked[stage] = markers, self.damage(markers)
            markers, problems = checked[stage]
            for unit, marker in markers.items():
                names = sorted(o for o in marker.outputs if o.startswith(prefix) and o.endswith(".parquet"))
                if not names:
                    continue
                if unit in problems:
                    damaged.extend(problems[unit])
                    continue
                parts.extend(TrustedPart(self.files.path_of(marker, name), name, stage, unit) for name in names)
        return sorted(parts, key=lambda p: p.relative), damaged

    def read(self, dataset: str, warn: bool = True) -> pa.Table:
        """All committed rows of a Parquet dataset (marker-trusted parts only) as one table with the registered
        schema; empty when there are none.

        Damaged parts are left out with one warning line (unless `warn` is False, for a caller that reports
        damage itself); a part that cannot be read is skipped too and recorded as damage of the unit that
        wrote it, so `mvpd status` shows that unit as damaged and `mvpd rerun` writes it again.
        """
        schema = spec(dataset).schema
        tables = []
        parts, damaged = self.trusted_parts(dataset)
        if damaged and warn:
            log.warning("%s", damage_line(dataset, damaged))
        for part in parts:
            try:
                tables.append(self.read_part(part.path, schema))
            except (pa.ArrowException, OSError) as error:
                log.warning("%s: unreadable Parquet part (%s); skipped, rerun stage %s to rewrite it",
                            part.path, error_text(error), part.stage)
                marker = self.marker(part.stage, part.unit)
                if marker is not None:
                    unreadable = Damage(part.stage, part.unit, part.relative, "is unreadable Parquet")
                    self.record_damage(part.stage, [(marker, [unreadable])])
        return pa.concat_tables(tables) if tables else schema.empty_table()

    def read_part(self, location: Path | str, schema: pa.Schema, **options: Any) -> pa.Table:
        """One trusted part (a Path on disk, a URL on a store: `trusted_parts`, `committed_part`), read in place."""
        return self.files.read_part(location, schema, **options)

    def video_store(self, embodiment: str, video_name: str) -> Path:
        """Where a video's Zarr store is on local disk (a unit stages it at the same relative path)."""
        return self.root / "videos" / embodiment / f"{video_name}.zarr"

    # ------------------------------------------------------------------------------ commits
    def staging(self, stage: str, unit: str) -> Path:
        """A fresh, empty staging folder for one attempt of a unit."""
        relative = f"{STAGING}/{stage}/{unit}.{socket.gethostname()}.{os.getpid()}"
        links.remove(self.root, relative)
        return links.make_folder(self.root, relative)

    def clear_staging(self, stage: str) -> None:
        """Remove what a stage's attempts staged and did not commit (failed units)."""
        links.remove(self.root, f"{STAGING}/{stage}")

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
        keys = self.files.commit(stage, unit, staging, files, outputs, previous)
        marker = Marker(stage, unit, config_hash, code_version(), outputs, rows, round(seconds, 3), attempt, host,
                        finished_at, info or {}, files, node=node, keys=keys)
        self.check_fence()
        self.files.write_marker(marker)
        if previous is not None:
            self.files.forget(previous, keys)
        return marker

    def commit_tables(self, stage: str, unit: str, tables: dict[str, pa.Table]) -> Marker:
        """Commit tables made outside a stage (the status table, test fixtures, tools) as the outputs of
        `stage`/`unit`: staged, moved into place and named by a marker, as a unit's are."""
        staging = self.staging(stage, unit)
        for dataset, table in tables.items():
            write_part(staging, dataset, unit, table)
        return self.commit_unit(stage, unit, staging, config_hash="", rows={d: t.num_rows for d, t in tables.items()},
                                seconds=0.0, attempt=1, finished_at=time.time(), host=socket.gethostname())

    def retire(self, stage: str, units: list[str]) -> None:
        """Remove outputs and markers of units the job no longer has (so queries never see stale rows)."""
        for unit in units:
            marker = self.marker(stage, unit)
            self.drop_marker(stage, unit)
            if marker is not None:
                self.files.retire(marker)

    # --------------------------------------------------------------------------------- logs
    def log_path(self, stage: str, unit: str) -> Path:
        """Where a unit's log is (its folder created, reached through no link); open it with `open_log`."""
        return links.make_folder(self.root, f"logs/{stage}") / f"{unit}.log"

    def open_log(self, stage: str, unit: str) -> IO[str]:
        """A unit's log opened for appending, following no link (a link there: RunLinkError)."""
        flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT
        return open(links.open_file(self.root, f"logs/{stage}/{unit}.log", flags), "a", encoding="utf-8")

    def check_links(self) -> None:
        """RunLinkError (one line naming it) when a link sits among the run's own folders: a driver or `gc`
        refuses such a run before it changes anything (`pipeline.store.links`)."""
        if isinstance(self.files, LocalFiles):
            found = links.run_links(self.root)
            if found:
                raise links.RunLinkError(links.link_repair(self.root, found[0])
                                         + (f" ({len(found) - 1} more links: `mvpd status` lists them)"
                                            if len(found) > 1 else ""))

    def upload_log(self, stage: str, unit: str) -> None:
        """Keep a unit's log with the run (on a store, a copy; best effort: a log is not an output)."""
        self.files.upload_log(stage, unit, self.log_path(stage, unit))


@dataclass(frozen=True)
class RunAddress:
    """A run folder as another process is handed it: where it is and the fence its commits check.

    Opened once in that process, after the driver's storage variables are set there (a store client made
    before would hold the worker's own endpoint and credentials).
    """

    location: str
    fence: str = ""

    def open(self) -> RunFolder:
        run = RunFolder(self.location)
        run.fence = self.fence
        return run


def as_run(run: RunFolder | str | os.PathLike[str]) -> RunFolder:
    """The run a caller of the Python API names (`load_video("runs/demo", ...)`): a RunFolder as it is, else
    the run folder at that path or URL, resolved here, once."""
    return run if isinstance(run, RunFolder) else RunFolder(run)


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
