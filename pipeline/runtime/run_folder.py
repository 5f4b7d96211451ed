"""The run folder: resolved job, Parquet datasets, Zarr videos, markers, logs and the run lock.

Layout (see schemas/README.md):
    job.yaml                    resolved job + its hash
    <dataset>/part-<unit>.parquet
    videos/<embodiment>/<video_name>.zarr
    _state/<stage>/<unit>.json  markers: the only proof that a unit is done
    _staging/<stage>/<unit>/    where a running unit writes before its commit
    logs/<stage>/<unit>.log
"""

from __future__ import annotations

import os
import shutil
import socket
import time
from pathlib import Path
from typing import Any

import pyarrow as pa
import yaml

from pipeline.config import ConfigError, Job, job_from_resolved
from pipeline.runtime import markers as marker_files
from pipeline.runtime.markers import (  # noqa: F401 - Marker and atomic_write_text are imported from here too
    STATE,
    Marker,
    atomic_write_text,
    code_version,
    describe_files,
)
from pipeline.runtime.tables import read_dataset

JOB_FILE = "job.yaml"
STAGING = "_staging"


class RunFolderError(ValueError):
    """A path that is not a usable run folder; the message says why and what to do."""


class RunFolder:
    """A run folder on local disk (or a shared file system mounted on every Ray node)."""

    def __init__(self, root: str | Path):
        self.root = Path(root).expanduser().resolve()

    # ------------------------------------------------------------------------------------ job
    @classmethod
    def prepare(cls, root: str | Path) -> "RunFolder":
        """Create the folder (or reopen a run); refuses a non-empty folder that is not a run."""
        run = cls(root)
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
        if not (run.root / JOB_FILE).is_file():
            raise RunFolderError(f"{run.root}: not a run folder (no {JOB_FILE}); give the folder `mvpd submit` wrote")
        return run

    def save_job(self, job: Job) -> None:
        text = yaml.safe_dump({"job_hash": job.hash(), "job": job.resolved()}, sort_keys=False)
        atomic_write_text(self.root / JOB_FILE, text)

    def job(self) -> Job:
        try:
            data = yaml.safe_load((self.root / JOB_FILE).read_text())
            return job_from_resolved(data["job"])
        except (KeyError, TypeError, ValueError) as error:
            raise ConfigError(f"{self.root / JOB_FILE}: unreadable resolved job ({error}); resubmit the job") from None

    # -------------------------------------------------------------------------------- datasets
    def read(self, dataset: str) -> pa.Table:
        """All committed rows of a Parquet dataset of this run (marker-trusted parts only)."""
        return read_dataset(self.root, dataset)

    def datasets(self) -> list[str]:
        """Names of the Parquet datasets some marker has committed parts of."""
        folder = self.root / STATE / marker_files.DATASET_INDEX
        return sorted(p.name for p in folder.iterdir() if p.is_dir() and any(p.iterdir())) if folder.is_dir() else []

    def video_store(self, embodiment: str, video_name: str) -> Path:
        return self.root / "videos" / embodiment / f"{video_name}.zarr"

    # --------------------------------------------------------------------------------- markers
    def marker_path(self, stage: str, unit: str) -> Path:
        return marker_files.marker_path(self.root, stage, unit)

    def marker(self, stage: str, unit: str) -> Marker | None:
        """The unit's marker; None when missing, unreadable or without a manifest (the unit runs again)."""
        return marker_files.read_marker(self.marker_path(stage, unit))

    def markers(self, stage: str) -> dict[str, Marker]:
        return marker_files.stage_markers(self.root, stage)

    def write_marker(self, marker: Marker) -> None:
        marker_files.write_marker(self.root, marker)

    def drop_marker(self, stage: str, unit: str) -> None:
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
        were just written and are read back from the page cache.
        """
        previous = self.marker(stage, unit)
        self.drop_marker(stage, unit)
        outputs = sorted(_staged_outputs(staging))
        files = describe_files(staging, outputs)
        self.commit(staging, outputs, previous.outputs if previous else [])
        marker = Marker(stage, unit, config_hash, code_version(), outputs, rows, round(seconds, 3), attempt, host,
                        finished_at, info or {}, files, node=node)
        self.write_marker(marker)
        return marker

    def commit(self, staging: Path, outputs: list[str], previous_outputs: list[str]) -> None:
        """Move the staged `outputs` (files or Zarr stores) into place, replacing earlier versions.

        Outputs of the unit's previous commit that this attempt did not produce are removed, so a
        rerun never leaves stale rows or videos behind.
        """
        for relative in outputs:
            target = self.root / relative
            target.parent.mkdir(parents=True, exist_ok=True)
            _replace(staging / relative, target)
        for relative in sorted(set(previous_outputs) - set(outputs)):
            _remove(self.root / relative)
        shutil.rmtree(staging, ignore_errors=True)

    def log_path(self, stage: str, unit: str) -> Path:
        path = self.root / "logs" / stage / f"{unit}.log"
        path.parent.mkdir(parents=True, exist_ok=True)
        return path


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
