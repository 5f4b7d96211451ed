"""Where a command may write: every `--out` is checked here before anything is written.

A command touches only what it was given. An output never goes to the file system root, never inside a
run folder (this run or another: a run's files are the ground truth and its markers name exactly what is
in it), and a folder output never goes into a non-empty folder that the same command did not write
(it would mix with, or replace, someone's files). A folder the command wrote holds a small tag file,
so writing into it again (a report brought up to date, a second export split) is allowed.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from pipeline.store.names import atomic_write_text, is_run_folder, replaced

TAG = ".mvpd-out"  # in a folder output: the command that wrote it


class OutPathError(ValueError):
    """An output path the command must not write to; the message names the option, the path and the fix."""


def check_out_location(path: Path, option: str = "--out") -> Path:
    """`path` resolved, when it is neither the file system root nor inside a run folder (alone: for a folder
    output whose command checks the folder's content itself, as `predict` does with its manifest)."""
    resolved = Path(path).expanduser().resolve()
    if resolved == Path(resolved.anchor):
        raise OutPathError(f"{option} {path}: is the file system root; give a file or folder of its own")
    run = next((folder for folder in resolved.parents if is_run_folder(folder)), None)
    if run is not None:
        raise OutPathError(f"{option} {path}: is inside the run folder {run}; write outside any run folder")
    return resolved


def check_out_file(path: Path, option: str = "--out") -> Path:
    """`path` resolved, when a file may be written there (see the module docstring); else OutPathError."""
    resolved = check_out_location(path, option)
    if resolved.is_dir():
        raise OutPathError(f"{option} {path}: is a folder; give a file path")
    return resolved


@contextmanager
def out_file(path: Path, option: str = "--out") -> Iterator[Path]:
    """Check `path` (check_out_file) and yield a temporary name beside it to write the file to; it is renamed
    over `path` when the block succeeds. So `path` names a new file: one that was a hard link of a run's file
    (or any other file) keeps its bytes."""
    with replaced(check_out_file(path, option)) as temporary:
        yield temporary


def check_out_folder(path: Path, command: str, option: str = "--out") -> Path:
    """`path` resolved, when `command` may write a folder there: new, empty, or written by `command` before."""
    resolved = check_out_location(path, option)
    if resolved.exists() and not resolved.is_dir():
        raise OutPathError(f"{option} {path}: is a file; give a folder path")
    if is_run_folder(resolved):  # whatever a tag file in it says: a tag counts only outside every run
        raise OutPathError(f"{option} {path}: is a run folder; write outside any run folder")
    if resolved.is_dir() and any(resolved.iterdir()) and _tag(resolved) != command:
        raise OutPathError(f"{option} {path}: is not empty and was not written by `{command}`; "
                           "choose a new or empty folder")
    return resolved


@contextmanager
def out_folder(path: Path, command: str, option: str = "--out") -> Iterator[Path]:
    """Check `path` for `command` (check_out_folder), yield it, and afterwards tag it as the command's own
    when anything was written into it, even if the command failed part-way (so that running it again
    may finish the job)."""
    resolved = check_out_folder(path, command, option)
    try:
        yield resolved
    finally:
        if resolved.is_dir() and any(resolved.iterdir()) and _tag(resolved) != command:
            atomic_write_text(resolved / TAG, command + "\n")  # a new file: a linked tag is replaced, not followed


def _tag(folder: Path) -> str | None:
    try:
        return (folder / TAG).read_text(encoding="utf-8").strip()
    except OSError:
        return None
