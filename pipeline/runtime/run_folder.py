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

import json
import os
import shutil
import socket
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa
import yaml

from pipeline.config import ConfigError, Job, job_from_resolved

JOB_FILE = "job.yaml"
STATE = "_state"
STAGING = "_staging"


class RunFolderError(ValueError):
    """A path that is not a usable run folder; the message says why and what to do."""


@dataclass
class Marker:
    """Proof that a unit committed: written last, atomically."""

    stage: str
    unit: str
    config_hash: str
    code_version: str
    outputs: list[str]
    rows: dict[str, int]
    seconds: float
    attempt: int
    host: str
    finished_at: float
    info: dict[str, Any] = field(default_factory=dict)


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
        """All committed rows of a Parquet dataset of this run."""
        from pipeline.io.tables import read_dataset

        return read_dataset(self.root, dataset)

    def datasets(self) -> list[str]:
        """Names of the Parquet datasets present in the run."""
        return sorted(p.name for p in self.root.iterdir() if p.is_dir() and any(p.glob("part-*.parquet")))

    def video_store(self, embodiment: str, video_name: str) -> Path:
        return self.root / "videos" / embodiment / f"{video_name}.zarr"

    # --------------------------------------------------------------------------------- markers
    def marker_path(self, stage: str, unit: str) -> Path:
        return self.root / STATE / stage / f"{unit}.json"

    def marker(self, stage: str, unit: str) -> Marker | None:
        path = self.marker_path(stage, unit)
        try:
            return Marker(**json.loads(path.read_text()))
        except FileNotFoundError:
            return None
        except (ValueError, TypeError):
            return None  # a damaged marker proves nothing: the unit runs again

    def markers(self, stage: str) -> dict[str, Marker]:
        folder = self.root / STATE / stage
        found = {}
        for path in sorted(folder.glob("*.json")) if folder.is_dir() else []:
            marker = self.marker(stage, path.stem)
            if marker is not None:
                found[marker.unit] = marker
        return found

    def write_marker(self, marker: Marker) -> None:
        atomic_write_text(self.marker_path(marker.stage, marker.unit), json.dumps(asdict(marker), indent=1, sort_keys=True))

    def drop_marker(self, stage: str, unit: str) -> None:
        self.marker_path(stage, unit).unlink(missing_ok=True)

    # --------------------------------------------------------------------------------- staging
    def staging(self, stage: str, unit: str) -> Path:
        """A fresh, empty staging folder for one attempt of a unit."""
        path = self.root / STAGING / stage / f"{unit}.{socket.gethostname()}.{os.getpid()}"
        shutil.rmtree(path, ignore_errors=True)
        path.mkdir(parents=True)
        return path

    def commit(self, staging: Path, previous_outputs: list[str]) -> list[str]:
        """Move every staged file or Zarr store into place, replacing earlier versions.

        Outputs of the unit's previous commit that this attempt did not produce are removed, so a
        rerun never leaves stale rows or videos behind. Returns the committed paths (relative).
        """
        outputs = sorted(_staged_outputs(staging))
        for relative in outputs:
            target = self.root / relative
            target.parent.mkdir(parents=True, exist_ok=True)
            _replace(staging / relative, target)
        for relative in sorted(set(previous_outputs) - set(outputs)):
            _remove(self.root / relative)
        shutil.rmtree(staging, ignore_errors=True)
        return outputs

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


def atomic_write_text(path: Path, text: str) -> None:
    """Write a small text file by temp file + rename, so readers see the old or the new file whole."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    temporary.write_text(text, encoding="utf-8")
    os.replace(temporary, path)
