"""The run folder's own names, and the checks that keep every name and path inside it.

Layout (schemas/README.md):
    job.yaml                    resolved job + its hash
    <dataset>/part-<unit>.parquet
    videos/<embodiment>/<video_name>.zarr
    _state/<stage>/<unit>.json  markers: the only proof that a unit is done
    _staging/<stage>/<unit>/    where a running unit writes before its commit
    _attempts/...               on object storage: the objects of each unit's attempt
    logs/<stage>/<unit>.log
"""

from __future__ import annotations

import os
import re
import secrets
import stat
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Iterable

JOB_FILE = "job.yaml"
STATE = "_state"
STAGING = "_staging"
ATTEMPTS = "_attempts"
# Which stages committed parts of which dataset: `_state/_datasets/<dataset>/<stage>` (empty files), so a
# reader of one dataset reads the markers of the stages that wrote it, not of every stage of the run.
DATASET_INDEX = "_datasets"
# The driver's status table is committed like a unit of this pseudo-stage (unit = the stage it describes).
STATUS_STAGE = "_status"
# The remote URL a run's local folder stands for (the URL only: never a credential).
REMOTE_FILE = ".remote-url"

# A name the run looks up (a stage, a unit, a video, a split, an embodiment): no separator and no leading
# dot, so it can never leave the folder it names (`..`, `/abs`, `e/v` are not plain).
_NAME = r"[A-Za-z0-9_\-][A-Za-z0-9_.\-]*"
PLAIN_NAME = re.compile(_NAME)
# A committed file or Zarr store, relative to the run: plain names joined by '/', at least two of them (a
# data folder and a name in it), the first not starting with '_' (`_state/`, `_staging/` and `_attempts/`
# are the run's own). Written for RE2 too: the marker index checks a whole manifest column with it.
RUN_PATH = re.compile(rf"[A-Za-z0-9\-][A-Za-z0-9_.\-]*(?:/{_NAME})+")
# Many paths at once, one per line: one regex call for a marker's ~40 paths instead of one each.
_RUN_PATH_LINES = re.compile(rf"(?:{RUN_PATH.pattern}\n)*")


class RunFolderError(ValueError):
    """A path that is not a usable run folder; the message says why and what to do."""


def is_run_folder(path: Path) -> bool:
    """True when `path` holds what `mvpd submit` writes first: `_state/`, the folder of its markers and lock (a
    real folder, not a link to one). A file named job.yaml alone (a user's project, a home folder) makes no
    run folder."""
    try:
        return stat.S_ISDIR(os.lstat(Path(path) / STATE).st_mode)
    except OSError:
        return False


def is_plain_name(name: str) -> bool:
    """True when `name` may be looked up inside one folder of the run (see PLAIN_NAME)."""
    return isinstance(name, str) and PLAIN_NAME.fullmatch(name) is not None


def is_run_path(path: str) -> bool:
    """True when `path` is a plain relative path of a committed output inside the run (see RUN_PATH):
    never absolute, never `..`, never the run's own bookkeeping."""
    return isinstance(path, str) and RUN_PATH.fullmatch(path) is not None


def first_bad_run_path(paths: Iterable[str]) -> str | None:
    """The first of `paths` that is not a run path (`is_run_path`), None when all are."""
    paths = list(paths)
    try:
        lines = "".join(f"{path}\n" for path in paths)
        # As many lines as paths: a path holding a line break is no run path, even if each line would be.
        if lines.count("\n") == len(paths) and _RUN_PATH_LINES.fullmatch(lines) is not None:
            return None
    except TypeError:  # not a string: found below
        pass
    return next(path for path in paths if not is_run_path(path))


def atomic_write_text(path: Path, text: str) -> None:
    """Write a small text file by temp file + rename, so readers see the old or the new file whole."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with replaced(path) as temporary:
        temporary.write_text(text, encoding="utf-8")


@contextmanager
def replaced(path: Path) -> Iterator[Path]:
    """A new temporary path beside `path` to write a file to, renamed over `path` when the block succeeds
    (removed when it fails), so that readers see the old or the new file whole and `path` then names a new
    file: a name that was a hard link of another file (a run's Parquet part) or a symbolic link to one
    leaves that file's bytes as they were. The temporary name keeps the suffix (writers that pick the format
    by it, matplotlib and OpenCV, still do) and is unguessable (no link can be planted there first)."""
    path = Path(path)
    temporary = path.with_name(f".{path.stem}.tmp-{os.getpid()}-{secrets.token_hex(4)}{path.suffix}")
    try:
        yield temporary
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)
